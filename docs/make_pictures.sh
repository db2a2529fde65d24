#!/usr/bin/env bash
# Regenerates the pictures of README's first screen into docs/images/, from commands of this
# repository only (no image tools needed: README sets the pictures side by side).
# The viewer's screenshot (view.png) needs a browser and is remade only with SPLAT4D_SHOT=1.
#
#   bash docs/make_pictures.sh        # from anywhere; about 3-4 min on 2 cores (the seed
#                                     # study ~2.5 min, the occluding fit ~15-25 s), after
#                                     # `cargo build --release`
#
# Not run by CI (the study alone takes minutes and CI runs it already as README's first
# example); run it when a renderer, a fit default or a scene behind a picture changes, look
# at every picture, and commit them. Work files go to out/pictures/.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
bin="${CARGO_TARGET_DIR:-target}/release/splat4d"
work=out/pictures
images=docs/images
mkdir -p "$work"

# 1. An occluding scene (docs/images/occluding_scene.json: two opaque slabs crossing in depth
#    and a moving blob, the scene of tests/it/fit_alpha.rs) beside its alpha fit from a
#    multi-view dataset, both seen from the same orbit camera at t = 0.5 (frame 3 of 8).
"$bin" dataset --scene "$images/occluding_scene.json" --views 10 --times 6 --size 48x48 --out "$work/occluding_set"
"$bin" fit --views "$work/occluding_set" --out "$work/occluding_fit.json"
for scene in "$images/occluding_scene.json:truth" "$work/occluding_fit.json:fit"; do
  "$bin" video --scene "${scene%%:*}" --orbit 0,0,0,3,25,8 --times 0.5 --up y --size 256x256 \
    --no-gif --no-mp4 --out "$work/occluding_${scene##*:}"
  cp "$work/occluding_${scene##*:}/orbit_t0.50/frame_0003.png" "$images/occluding_${scene##*:}.png"
done

# 2. The glTF sample BoxAnimated imported as additive and as opaque (alpha) surfels, at t = 1.2.
for blend in additive alpha; do
  "$bin" import-gltf tests/data/gltf/BoxAnimated.gltf --kernels 4000 --times 5 --blend "$blend" \
    --out "$work/box_$blend.json"
  "$bin" render --scene "$work/box_$blend.json" --camera "$images/box_animated_camera.json" --time 1.2 \
    --out "$images/box_animated_$blend.png"
done

# 3. The seed study (what `cargo run --release` runs): PSNR per time from the held-out cameras.
"$bin" report --out "$work/report"
cp "$work/report/psnr_per_time.png" "$images/seed_psnr_per_time.png"

# 4. The viewer (docs/images/view.png), only when asked (SPLAT4D_SHOT=1) and a Chromium is on
#    PATH: the ignored test of tests/it/view.rs drives it headless on the fitted occluding
#    scene with its dataset (about 1 min more, with the test build).
if [ "${SPLAT4D_SHOT:-0}" = 1 ]; then
  SPLAT4D_SHOT_SCENE="$work/occluding_fit.json" SPLAT4D_SHOT_VIEWS="$work/occluding_set" \
    SPLAT4D_SHOT_OUT="$images/view.png" \
    cargo test --release --test it view::readme_screenshot -- --ignored
fi

echo "pictures written to $images/: look at each before committing"
