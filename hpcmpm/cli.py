"""The `hpcmpm` command: argument parsing and error reporting only.

Every `HpcmpmError` becomes one line per problem on stderr (``hpcmpm: error: ...``) and its
exit code; nothing a user can cause ends in a traceback.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from . import __version__
from .errors import HpcmpmError


def _rank() -> int:
    # The launcher's environment says which rank this is, so the CLI needs no MPI import.
    for var in ("PMI_RANK", "OMPI_COMM_WORLD_RANK", "PMIX_RANK", "SLURM_PROCID"):
        if var in os.environ:
            try:
                return int(os.environ[var])
            except ValueError:
                pass
    return 0


def configure_logging(quiet: bool = False) -> None:
    rank = _rank()
    level = logging.WARNING if rank or quiet else logging.INFO
    logging.basicConfig(level=level, stream=sys.stderr,
                        format=f"[%(asctime)s %(levelname)s rank {rank}] %(message)s",
                        datefmt="%H:%M:%S")


def _validate(args) -> int:
    from .scene import load_scene
    from .startup import validate_report

    print(validate_report(load_scene(args.scene, args.set or [])))
    return 0


def _run(args) -> int:
    from . import numba_cache

    numba_cache.configure()  # before the runner imports numba
    from .runner import run_command

    return run_command(args)


def _restart(args) -> int:
    from . import numba_cache

    numba_cache.configure()
    from .runner import restart_command

    return restart_command(args)


def _info(args) -> int:
    from .io.info import info_command

    return info_command(args)


def _jobscript(args) -> int:
    from .jobs import jobscript_command

    return jobscript_command(args)


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

    return plot_command(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hpcmpm", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"hpcmpm {__version__}")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    run = verbs.add_parser("run", help="run a scene")
    run.add_argument("scene")
    run.add_argument("--out", help="output folder (default runs/<scene name>)")
    run.add_argument("--end-time", type=float, help="override simulation.end_time")
    run.add_argument("--set", action="append", metavar="KEY.PATH=VALUE",
                     help="override a scene value, e.g. simulation.cfl=0.3 (repeatable)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument("--force", action="store_true", help="replace another run's output")
    run.add_argument("--checkpoint-every", type=int, metavar="N", help="checkpoint every N steps")
    run.add_argument("--checkpoint-wall", metavar="HH:MM:SS",
                     help="checkpoint every HH:MM:SS of wall time")
    run.add_argument("--debug-checks", action="store_true",
                     help="check the global particle count every step")
    run.add_argument("--dry-run", action="store_true",
                     help="sample and decompose, report counts and memory per rank, exit")
    run.set_defaults(handler=_run)

    restart = verbs.add_parser("restart", help="continue from a checkpoint")
    restart.add_argument("checkpoint")
    restart.add_argument("--end-time", type=float)
    restart.add_argument("--out", help="output folder (default: the checkpoint's folder)")
    restart.add_argument("--quiet", action="store_true")
    restart.add_argument("--checkpoint-every", type=int, metavar="N")
    restart.add_argument("--checkpoint-wall", metavar="HH:MM:SS")
    restart.set_defaults(handler=_restart)

    validate = verbs.add_parser("validate", help="check a scene file")
    validate.add_argument("scene")
    validate.add_argument("--set", action="append", metavar="KEY.PATH=VALUE")
    validate.set_defaults(handler=_validate)

    info = verbs.add_parser("info", help="describe a frame or checkpoint file")
    info.add_argument("file")
    info.set_defaults(handler=_info)

    job = verbs.add_parser("jobscript", help="render a SLURM or PBS job script")
    job.add_argument("scene")
    job.add_argument("--scheduler", choices=("slurm", "pbs"), required=True)
    job.add_argument("--nodes", type=int, default=1)
    job.add_argument("--ranks-per-node", type=int, default=1)
    job.add_argument("--time", required=True, metavar="HH:MM:SS")
    job.add_argument("--out", help="run output folder (default runs/<scene name>)")
    job.add_argument("--activate", help="shell line that activates the environment")
    job.add_argument("--output", "-o", help="write the script here instead of stdout")
    job.add_argument("extra", nargs="*", help="extra `hpcmpm run` arguments (after --)")
    job.set_defaults(handler=_jobscript)

    render = verbs.add_parser("render", help="pictures and a movie of a run (docs/output.md)")
    render.add_argument("run_dir")
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

    plot = verbs.add_parser("plot", help="time series of a run's diagnostics to PNG + CSV")
    plot.add_argument("run_dir")
    plot.add_argument("--out", help="output folder (default RUN_DIR)")
    plot.set_defaults(handler=_plot)

    bench = verbs.add_parser("bench", help="run the benchmarks (see BENCHMARKS.md)",
                             add_help=False)
    bench.add_argument("bench_args", nargs=argparse.REMAINDER)
    bench.set_defaults(handler=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        # argparse.REMAINDER does not take a leading option (`hpcmpm bench --help`), so the
        # bench verb collects those itself; every other verb rejects them as usual.
        if args.verb != "bench":
            parser.error(f"unrecognized arguments: {' '.join(unknown)}")
        args.bench_args = unknown + list(args.bench_args)
    configure_logging(getattr(args, "quiet", False))
    try:
        return int(args.handler(args) or 0)
    except HpcmpmError as exc:
        for line in str(exc).splitlines() or [type(exc).__name__]:
            print(f"hpcmpm: error: {line}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("hpcmpm: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
