#!/usr/bin/env bash
# CI, after the main test command: the fit spread over MPI ranks (cargo feature `mpi`).
# Installs Debian's Open MPI (and libclang for the binding's build), builds with
# `--features mpi` and runs the MPI tests (tests/it/mpi.rs): `mpirun -n 2` and `-n 3`, with
# --oversubscribe (CI has fewer cores than ranks) and --allow-run-as-root (CI runs as root),
# each fitted scene compared byte for byte with the one-process scene. The plain build and
# `cargo test --release` above need none of this.
set -euo pipefail
cd "$(dirname "$0")/.."
dpkg -s libopenmpi-dev openmpi-bin libclang-dev >/dev/null 2>&1 \
    || (apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y libopenmpi-dev openmpi-bin clang libclang-dev)
cargo clippy --features mpi -- -D warnings
cargo test --release --features mpi --test it mpi::
