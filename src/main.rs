//! The `splat4d` command line: parse → a task → print. Every error is printed once, here,
//! and its kind decides the exit status (clap's own usage errors exit 2 as well):
//!
//! | kind | exit |
//! |---|---|
//! | input: a file that cannot be read, is malformed, or holds an invalid value | 2 |
//! | usage: flags that cannot be carried out as given | 2 |
//! | output: a file that cannot be written | 3 |
//! | numeric: a fit that diverged, a result that is not finite | 4 |

mod cli;

/// Large blocks on transparent huge pages ([`cli::allocator`]): a fresh command's first
/// frame takes one page fault per 2 MiB instead of one per 4 KiB.
#[global_allocator]
static ALLOCATOR: cli::allocator::HugePages = cli::allocator::HugePages;

use std::process::ExitCode;

use splat4d::ErrorKind;

fn exit_code(kind: ErrorKind) -> u8 {
    match kind {
        ErrorKind::Input | ErrorKind::Usage => 2,
        ErrorKind::Output => 3,
        ErrorKind::Numeric => 4,
    }
}

fn main() -> ExitCode {
    cli::allocator::tune_heap();
    let args = <cli::Cli as clap::Parser>::parse();
    // Under `mpirun` (cargo feature `mpi`): MPI runs until this is dropped, after the command.
    #[cfg(feature = "mpi")]
    let _mpi = cli::mpi::start();
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            let args: Vec<String> = std::env::args().collect();
            let given = cli::flags::given_flags(args.iter().cloned());
            let known = cli::flags::command_flags(&args);
            let error = cli::flags::name_flags(error, &given, &known);
            let code = exit_code(error.kind());
            #[cfg(feature = "mpi")]
            if let Some((rank, size)) = cli::mpi::spread() {
                // One rank failing stops them all, none left waiting for it.
                eprintln!("error: rank {rank} of {size}: {error}");
                cli::mpi::stop_all(code);
            }
            eprintln!("error: {error}");
            ExitCode::from(code)
        }
    }
}
