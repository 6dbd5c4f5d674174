"""The ``gbo`` command line: ``gbo demo``, and the sub-commands of later modules.

Each sub-command lives in its own module with an ``add_parser(subparsers)``
function; this file only wires them together and holds the one error boundary:
bad input (an argument out of range, a bad file, a value the Python API
refuses with ``ValueError`` or ``TypeError``) ends every command with exit
status 2 and one line on stderr that names the argument, file or value;
``gbo --debug ...`` shows the traceback instead. The argument types live in
:mod:`evaluation.cli_args`.
"""

from __future__ import annotations

import argparse
import atexit
import importlib
import multiprocessing
import os
import signal
import sys
import threading

import gbo_envs  # noqa: F401  (registers the envs)
from evaluation import allocator
from evaluation.cli_args import (
    EXIT_BAD_INPUT,
    EnvId,
    Handler,
    OneLineParser,
    OutputClosed,
    check_env_id,
    env_id,
    error_message,
    import_modules,
    positive_int,
    seed,
)

__all__ = ["main"]

#: Modules that contribute sub-commands through ``add_parser(subparsers)``.
SUBCOMMAND_MODULES: tuple[str, ...] = ("evaluation.bench_parser", "evaluation.tune_parser", "evaluation.twin_parser")


def build_parser() -> argparse.ArgumentParser:
    """The ``gbo`` argument parser with every available sub-command."""
    parser = OneLineParser(prog="gbo", description="Data-efficient controller tuning with guided BO.",
                           epilog="Example:\n  gbo demo\n  gbo tune --budget 20 && gbo export --csv "
                                  "out/run.csv && gbo twin diagnose out/run.csv",
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--debug", action="store_true",
                        help="show the full traceback of an error (allowed anywhere on the line)")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="ground truth, figures and a short tuning run on the default plant",
                          description="Compute the ground-truth cost surface of a plant, plot it, and tune it "
                                      "briefly with each available tuner.",
                          epilog="Example:\n  gbo demo --out out/demo --budget 10",
                          formatter_class=argparse.RawDescriptionHelpFormatter)
    demo.add_argument("--out", default="out/demo", help="output folder for the PNGs (default: out/demo)")
    demo.add_argument("--env", type=env_id, default=EnvId("gbo_envs/DCMotor-v0"),
                      help="env id (default: gbo_envs/DCMotor-v0)")
    demo.add_argument("--seed", type=seed, default=0, help="seed of the first tuning run (default: 0)")
    demo.add_argument("--budget", type=positive_int, default=20, help="plant experiments per tuner (default: 20)")
    demo.add_argument("--seeds", type=positive_int, default=3,
                      help="tuning runs per tuner, from --seed on; the convergence plot shows their mean and 95 %% "
                           "confidence band (default: 3)")
    demo.add_argument("--no-tuners", action="store_true", help="only the ground truth and its figures")
    demo.add_argument("--quiet", action="store_true", help="no progress bars (default: on stderr when a terminal)")
    demo.set_defaults(handler=Handler("evaluation.demo:demo_command"))
    for module in SUBCOMMAND_MODULES:
        try:
            importlib.import_module(module).add_parser(sub)
        except ImportError as exc:  # an optional extra is missing: say so instead of hiding the command
            sub.add_parser(module.rsplit(".", 1)[-1], help=f"unavailable: {exc}")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gbo`` script; returns the exit status (2: bad input, one line on stderr)."""
    allocator.retain_freed_memory()  # the twin fits' large temporaries are reused, not faulted in again
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv  # anywhere on the line, not only before the sub-command
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    args.debug = debug
    command = " ".join(["gbo", args.command, *(getattr(args, key) for key in vars(args)
                                               if key.endswith("_command") and getattr(args, key))])
    if not hasattr(args, "handler"):
        print(f"{command}: this command needs an optional extra; see README", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        _prepare(args)
        return int(args.handler(args) or 0)
    except (BrokenPipeError, OutputClosed):  # the reader of stdout went away (gbo ... | head): end quietly
        return _output_closed()
    except KeyboardInterrupt:
        if args.debug:
            raise
        print(f"{command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        message = error_message(exc, db=getattr(args, "db", None))
        if message is None:  # a bug, not bad input: still one line, and the way to the traceback
            print(f"{command}: internal error: {type(exc).__name__}: {exc} (rerun with gbo --debug for the "
                  "traceback)", file=sys.stderr)
            return 1
        print(f"{command}: error: {' '.join(message.split())}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _output_closed() -> int:
    """Exit status 1 after the reader of stdout went away, with stdout sent to ``os.devnull`` so that the
    interpreter's last flush does not fail again (Python's documentation, "Note on SIGPIPE")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # a stdout without a file descriptor (an in-process caller)
        pass
    return 1


def _prepare(args: argparse.Namespace) -> None:
    """Run the ``--import`` modules, then check every ``--env`` against the registry they may extend."""
    imports = getattr(args, "imports", None) or []
    import_modules(imports)
    for key, value in vars(args).items():
        if isinstance(value, EnvId):
            setattr(args, key, check_env_id(value, imported=imports))


def run() -> int:
    """The ``gbo`` script: :func:`main`, then, when nothing else runs, an exit that does not free the interpreter's
    objects one by one.

    A command leaves hundreds of MB of modules, compiled kernels and remembered plants behind; the
    interpreter's teardown took 0.5 s of every ``gbo twin diagnose`` (6-11 s). When no child process and
    no other non-daemon thread is alive, the exit handlers run, the output streams are flushed and the
    process ends at once (mypy exits the same way). Otherwise (a pool of ``gbo bench`` that is still shutting
    down) the exit is the normal one, which waits for them. In-process callers use :func:`main`, which returns.
    """
    code = main()
    interrupted = _quiet_interrupt()
    if not _alone():
        _shut_down_workers()
        return 130 if interrupted else code
    atexit._run_exitfuncs()  # what sys.exit would run
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except OSError:  # a reader that went away (gbo ... | head): nothing left to write to
            pass
    os._exit(130 if interrupted else code)


def _quiet_interrupt() -> list:
    """From now on, Ctrl-C prints one line and the exit status becomes 130, but the shutdown goes on: the
    command is done, and a ``KeyboardInterrupt`` would only break the worker pools' shutdown (loky's exit
    handler) with a traceback, or, cut short, leave their semaphores and memory-mapped folders behind. A
    second Ctrl-C ends the process at once. Returns the list that records the interruption."""
    interrupted: list = []

    def handler(signum, frame):
        if interrupted:
            os._exit(130)
        interrupted.append(signum)
        os.write(2, b"gbo: interrupted; the command had finished, its worker processes are shutting down\n")

    try:
        signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread
        pass
    return interrupted


def _shut_down_workers() -> None:
    """Shut joblib's reusable loky executor down now, as the interpreter's exit would, but under the quiet
    Ctrl-C of :func:`_quiet_interrupt` (its workers end; the pool of ``gbo bench`` is one)."""
    module = sys.modules.get("joblib.externals.loky.reusable_executor")
    executor = getattr(module, "_executor", None)
    if executor is not None:
        executor.shutdown(wait=True)


def _alone() -> bool:
    """Whether no child process and no non-daemon thread but the main one is alive."""
    threads = (t for t in threading.enumerate() if t is not threading.main_thread())
    return not multiprocessing.active_children() and not any(t.is_alive() and not t.daemon for t in threads)


if __name__ == "__main__":
    raise SystemExit(run())
