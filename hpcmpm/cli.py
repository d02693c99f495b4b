"""The `hpcmpm` command line: argument parsing and error reporting only (the verbs live in
runner, io.info, jobs and bench).

Every `HpcmpmError` becomes one line per problem on stderr (``hpcmpm: error: ...``) and its
exit code; nothing a user can cause ends in a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
from pathlib import Path

from . import __version__
from .errors import HpcmpmError

log = logging.getLogger(__name__)


def _rank() -> int:
    # The launcher's environment says which rank this is, so the CLI needs no MPI import.
    from .launcher import launcher_rank

    return launcher_rank()


def configure_logging(quiet: bool = False) -> None:
    rank = _rank()
    level = logging.WARNING if rank or quiet else logging.INFO
    logging.basicConfig(level=level, stream=sys.stderr,
                        format=f"[%(asctime)s %(levelname)s rank {rank}] %(message)s",
                        datefmt="%H:%M:%S")


@contextlib.contextmanager
def floating_point_errors_logged():
    """numpy's floating-point errors (overflow, invalid, divide) go to the debug log, once per
    place in hpcmpm, instead of RuntimeWarnings on stderr. A scene value beyond the float
    range (a density of 1e308, a collider speed of 1e308) printed up to four warnings before
    the run's own one-line error; a non-finite state is still found and reported by the
    run's checks (the health check before every step and frame, the time step's advance).
    Library calls outside the command line keep numpy's warnings."""
    import numpy as np

    seen = set()
    ours = f"{os.sep}hpcmpm{os.sep}"

    def report(kind, _flag):
        frame = sys._getframe(1)  # the innermost caller of ours: no source lines read
        while frame is not None and ours not in frame.f_code.co_filename:
            frame = frame.f_back
        where = "numpy" if frame is None else \
            f"{Path(frame.f_code.co_filename).name}:{frame.f_lineno}"
        if (kind, where) not in seen:
            seen.add((kind, where))
            log.debug("floating-point %s at %s", kind, where)

    with np.errstate(over="call", invalid="call", divide="call", call=report):
        yield


def _validate(args) -> int:
    """Each scene's summary, or its problems (one line each); with several scenes every one
    is checked, a header names each, and the exit code is the worst of theirs."""
    from .scene import load_scene
    from .startup import validate_report

    scenes = args.scene
    code = 0
    for path in scenes:
        if len(scenes) > 1:
            print(f"== {path}", flush=True)
        try:
            print(validate_report(load_scene(path, args.set or [])), flush=True)
        except HpcmpmError as exc:
            report_error(exc)
            code = max(code, exc.exit_code)
    return code


def _run(args) -> int:
    from . import numba_cache
    from .signals import SignalFlag

    # From the first moment: a scheduler's warning during imports or compilation is kept for
    # the run loop (which checkpoints on it) instead of killing the process.
    with SignalFlag() as flag:
        numba_cache.configure()  # before the runner imports numba
        from .runner import run_command

        return run_command(args, flag)


def _restart(args) -> int:
    from . import numba_cache
    from .signals import SignalFlag

    with SignalFlag() as flag:
        numba_cache.configure()
        from .runner import restart_command

        return restart_command(args, flag)


def _info(args) -> int:
    from .io.info import info_command

    return info_command(args)


def _jobscript(args) -> int:
    from .jobs import jobscript_command

    return jobscript_command(args, build_parser())


def _bench(args) -> int:
    from .bench import bench_command

    return bench_command(args)


def _render(args) -> int:
    from . import numba_cache

    numba_cache.configure()  # the 3D renderer's kernel is numba
    from .viz.render import render_command

    return render_command(args)


def _plot(args) -> int:
    from .viz.diagnostics import plot_command

    if _rank() != 0:
        # `mpiexec -n N hpcmpm plot`: one process writes the files (N would race on them).
        return 0
    return plot_command(args)


DESCRIPTION = ("hpcmpm: an MPI-distributed Material Point Method (MPM) solver with peridynamics "
               "and numba kernels. "
               "Runs TOML scenes on any number of ranks (mpiexec -n N hpcmpm run SCENE), writes "
               "HDF5 frames with an XDMF series for ParaView and checkpoints that restart on any "
               "rank count.")
EPILOG = ("Exit codes: 0 done, 2 invalid scene or arguments, 3 numerical instability, 4 a "
          "checkpoint or frame that cannot be read or written, 5 output folder holds another "
          "run, 6 not a readable frame or checkpoint (info), 75 checkpoint written on "
          "SIGTERM/SIGUSR1. Scene format: docs/scene-format.md.")
CHECKPOINT_EVERY_HELP = "also write a checkpoint every N steps (default: output.checkpoint_every)"
DEBUG_CHECKS_HELP = "check the global particle count every step"
CHECKPOINT_WALL_HELP = "also write a checkpoint every HH:MM:SS (or seconds) of wall time"
QUIET_HELP = "no progress bar (warnings and errors are still printed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hpcmpm", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"hpcmpm {__version__}")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB",
                                  help="what to do; `hpcmpm VERB --help` for its options")

    run = verbs.add_parser("run", help="run a scene", description="Run a scene from t = 0.")
    run.add_argument("scene", help="the scene's TOML file")
    run.add_argument("--out", help="output folder (default runs/<scene name>)")
    run.add_argument("--end-time", type=float, metavar="T",
                     help="simulated time to stop at, > 0 (default: simulation.end_time)")
    run.add_argument("--set", action="append", metavar="KEY.PATH=VALUE",
                     help="override a scene value, e.g. simulation.cfl=0.3 or "
                          "materials.rubber.E=2e4 (repeatable)")
    run.add_argument("--quiet", action="store_true", help=QUIET_HELP)
    run.add_argument("--force", action="store_true", help="replace another run's output")
    run.add_argument("--checkpoint-every", type=int, metavar="N", help=CHECKPOINT_EVERY_HELP)
    run.add_argument("--checkpoint-wall", metavar="HH:MM:SS", help=CHECKPOINT_WALL_HELP)
    run.add_argument("--debug-checks", action="store_true", help=DEBUG_CHECKS_HELP)
    run.add_argument("--dry-run", action="store_true",
                     help="sample and decompose, report counts and memory per rank, exit")
    run.set_defaults(handler=_run)

    restart = verbs.add_parser("restart", help="continue from a checkpoint",
                               description="Continue a run from a checkpoint, on any rank count.")
    restart.add_argument("checkpoint", help="a ckpt_SSSSSSSSS.h5 file of the run, or the run's "
                         "folder (its newest checkpoint)")
    restart.add_argument("--end-time", type=float, metavar="T",
                         help="simulated time to stop at, later than the checkpoint's "
                              "(default: the end time of the run)")
    restart.add_argument("--out", help="output folder (default: the checkpoint's folder)")
    restart.add_argument("--force", action="store_true",
                         help="replace another run's output in --out")
    restart.add_argument("--quiet", action="store_true", help=QUIET_HELP)
    restart.add_argument("--checkpoint-every", type=int, metavar="N", help=CHECKPOINT_EVERY_HELP)
    restart.add_argument("--checkpoint-wall", metavar="HH:MM:SS", help=CHECKPOINT_WALL_HELP)
    restart.add_argument("--debug-checks", action="store_true", help=DEBUG_CHECKS_HELP)
    restart.set_defaults(handler=_restart)

    validate = verbs.add_parser("validate", help="check a scene file",
                                description="Check a scene: every problem on its own line "
                                            "(exit 2), or a summary of what it holds.")
    validate.add_argument("scene", nargs="+", help="the scene's TOML file (several: each is "
                          "checked, the exit code is the worst)")
    validate.add_argument("--set", action="append", metavar="KEY.PATH=VALUE",
                          help="override a scene value before checking (repeatable)")
    validate.set_defaults(handler=_validate)

    info = verbs.add_parser("info", help="describe a frame, a checkpoint or a run folder",
                            description="What a frame or checkpoint holds; a checkpoint is also "
                                        "verified against its checksums. For a run folder: its "
                                        "frames and checkpoints, whether it reached its end "
                                        "time, and the command that continues it.")
    info.add_argument("file", help="a frame_NNNNNN.h5 or ckpt_SSSSSSSSS.h5 file, or a run "
                      "folder (its frames, checkpoints, state and how to continue it)")
    info.set_defaults(handler=_info)

    job = verbs.add_parser("jobscript", help="render a SLURM or PBS job script",
                           description="Render a job script that runs the scene, checkpoints "
                                       "before the wall time and requeues itself.")
    job.add_argument("scene", help="the scene's TOML file (checked now)")
    job.add_argument("--scheduler", choices=("slurm", "pbs"), required=True,
                     help="the batch system")
    job.add_argument("--nodes", type=int, default=1, help="nodes to ask for (default 1)")
    job.add_argument("--ranks-per-node", type=int, default=1,
                     help="MPI ranks per node (default 1)")
    job.add_argument("--time", required=True, metavar="HH:MM:SS", help="the job's wall time")
    job.add_argument("--out", help="run output folder (default runs/<scene name>); created now, "
                                   "since the scheduler opens the job's log in it")
    job.add_argument("--activate", help="shell line that activates the environment "
                                        "(default: source this environment's bin/activate)")
    job.add_argument("--output", "-o", help="write the script here instead of stdout")
    job.add_argument("--mpi", metavar="TYPE", default="pmi2",
                     help="SLURM: srun's --mpi plugin that gives the MPI library its ranks "
                          "(default pmi2, for MPICH; pmix for many site Open MPIs; 'default' "
                          "leaves the cluster's MpiDefault)")
    job.add_argument("extra", nargs="*", help="extra `hpcmpm run` arguments (after --)")
    job.set_defaults(handler=_jobscript)

    render = verbs.add_parser("render", help="pictures and a movie of a run (docs/output.md)",
                              description="A PNG of each frame of a run, coloured by a field, "
                                          "and a movie of them; the frames are split between "
                                          "the MPI ranks.")
    render.add_argument("run_dir", help="a run's output folder (frames and particles.xdmf)")
    render.add_argument("--field", metavar="NAME[:COMPONENT]",
                        help="colour by this frame field (default speed), e.g. material, J, v:x")
    render.add_argument("--frames", metavar="A:B:K", help="slice of the frames (default all)")
    render.add_argument("--out", help="folder of the PNGs and movie (default RUN_DIR/render)")
    render.add_argument("--size", metavar="WxH", help="picture size in pixels (default 960x720)")
    render.add_argument("--camera", metavar="eye=X,Y,Z;target=X,Y,Z;up=X,Y,Z;fov=DEG",
                        help="3D camera (default: frames the domain)")
    render.add_argument("--fps", type=float, default=12.0, help="movie frame rate")
    render.add_argument("--movie", default="auto", choices=("auto", "mp4", "gif", "webp", "none"),
                        help="movie format (auto: MP4 if ffmpeg is available, else GIF)")
    render.add_argument("--quiet", action="store_true", help="no progress bar")
    render.set_defaults(handler=_render)

    plot = verbs.add_parser("plot", help="time series of a run's diagnostics to PNG + CSV",
                            description="The frames' diagnostics (mass, momentum, energies, "
                                        "solver counts) over time: diagnostics.csv and "
                                        "diagnostics.png.")
    plot.add_argument("run_dir", help="a run's output folder (frames)")
    plot.add_argument("--out", help="output folder (default RUN_DIR)")
    plot.set_defaults(handler=_plot)

    bench = verbs.add_parser("bench", help="run the benchmarks (see BENCHMARKS.md)",
                             add_help=False)
    bench.add_argument("bench_args", nargs=argparse.REMAINDER,
                       help="the benchmark's own arguments (hpcmpm bench --help)")
    bench.set_defaults(handler=_bench)
    return parser


# Options whose value may begin with "-" without being a number (`--frames -3:`, the last
# three frames), which argparse would otherwise take for an option and refuse.
DASH_VALUE_OPTIONS = ("--frames",)


def _attach_dash_values(argv: list[str]) -> list[str]:
    """``--frames -3:`` -> ``--frames=-3:`` (the same for every DASH_VALUE_OPTIONS)."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] in DASH_VALUE_OPTIONS and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


# Verbs that use no MPI: under a launcher every copy would print the same lines.
SINGLE_PROCESS_VERBS = ("validate", "info", "jobscript")


def report_error(exc: HpcmpmError) -> None:
    """Every HpcmpmError is raised on all ranks alike (errors.py): rank 0 tells the user, once
    per job, one stderr line per line of the message."""
    if _rank() == 0:
        label = getattr(exc, "label", "error")
        for line in str(exc).splitlines() or [type(exc).__name__]:
            print(f"hpcmpm: {label}: {line}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = _attach_dash_values(list(sys.argv[1:] if argv is None else argv))
    args, unknown = parser.parse_known_args(argv)
    if unknown and args.verb == "jobscript" and unknown[0] == "--":
        # `jobscript ... SCENE -o x.sh -- --end-time 1`: argparse gave SCENE an empty `extra`
        # before the options that follow it; what comes after "--" is that `extra`.
        args.extra = list(args.extra) + unknown[1:]
    elif unknown:
        # argparse.REMAINDER does not take a leading option (`hpcmpm bench --help`), so the
        # bench verb collects those itself; every other verb rejects them as usual.
        if args.verb != "bench":
            parser.error(f"unrecognized arguments: {' '.join(unknown)}")
        args.bench_args = unknown + list(args.bench_args)
    configure_logging(getattr(args, "quiet", False))
    if args.verb in SINGLE_PROCESS_VERBS and _rank() != 0:
        # `mpiexec -n N hpcmpm validate ...` runs N copies of a single-process verb: each
        # does the work and exits with its code, rank 0 alone prints (as errors are).
        sys.stdout = open(os.devnull, "w")
    try:
        with floating_point_errors_logged():
            return int(args.handler(args) or 0)
    except HpcmpmError as exc:
        report_error(exc)
        return exc.exit_code
    except KeyboardInterrupt:
        print("hpcmpm: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`hpcmpm info RUN | head`): stop quietly, as a pipe's writer
        # does, and keep Python from reporting the failed flush of stdout at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
