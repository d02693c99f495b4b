"""`hpcmpm jobscript`: render a SLURM or PBS script from the templates in ``jobs/``.

The rendered script activates the environment, launches the ranks, forwards the scheduler's
early-warning signal so the run checkpoints before the wall time, and resumes from the newest
checkpoint when the job is requeued or resubmitted.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from string import Template

from .errors import EXIT_CHECKPOINTED_ON_SIGNAL, HpcmpmError

SCHEDULERS = ("slurm", "pbs")
# Seconds before the wall time at which the run is told to checkpoint: enough for one step
# plus a checkpoint write of a large run.
SIGNAL_MARGIN = 300


class JobScriptError(HpcmpmError):
    exit_code = 2


def template_path(scheduler: str) -> Path:
    """The template, from the source tree or from an installed ``share/hpcmpm/jobs``."""
    name = f"{scheduler}.sh.in"
    for folder in (Path(__file__).resolve().parents[1] / "jobs",
                   Path(sys.prefix) / "share" / "hpcmpm" / "jobs"):
        if (folder / name).is_file():
            return folder / name
    raise JobScriptError(f"job template {name} not found (looked in the source tree and "
                         f"{Path(sys.prefix) / 'share/hpcmpm/jobs'})")


def parse_walltime(text: str) -> int:
    parts = text.split(":")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or min(values) < 0 or values[1] > 59 or values[2] > 59:
        raise JobScriptError(f"--time: expected HH:MM:SS, got {text!r}")
    return values[0] * 3600 + values[1] * 60 + values[2]


def render(scheduler: str, scene: str, nodes: int, ranks_per_node: int, walltime: str,
           out_dir: str | None = None, activate: str | None = None,
           extra_args: list[str] | None = None, script_path: str = "job.sh") -> str:
    if scheduler not in SCHEDULERS:
        raise JobScriptError(f"--scheduler: must be one of {', '.join(SCHEDULERS)}, got {scheduler!r}")
    if nodes < 1 or ranks_per_node < 1:
        raise JobScriptError("--nodes and --ranks-per-node must be >= 1")
    seconds = parse_walltime(walltime)
    margin = min(SIGNAL_MARGIN, max(seconds // 10, 10))
    out_dir = out_dir or f"runs/{Path(scene).stem}"
    extra = " " + " ".join(shlex.quote(a) for a in extra_args) if extra_args else ""
    mapping = {
        "job_name": Path(scene).stem, "nodes": nodes, "ranks_per_node": ranks_per_node,
        "walltime": walltime, "walltime_seconds": seconds, "signal_margin": margin,
        "exit_code": EXIT_CHECKPOINTED_ON_SIGNAL, "scene": scene, "out_dir": out_dir,
        "activate": activate or f"source {shlex.quote(str(Path(sys.prefix) / 'bin' / 'activate'))}",
        "extra_args": extra, "end_time_arg": "", "script_path": script_path,
    }
    return Template(template_path(scheduler).read_text()).safe_substitute(mapping)


def jobscript_command(args) -> int:
    text = render(args.scheduler, args.scene, args.nodes, args.ranks_per_node, args.time,
                  out_dir=getattr(args, "out", None), activate=getattr(args, "activate", None),
                  extra_args=getattr(args, "extra", None),
                  script_path=getattr(args, "output", None) or "job.sh")
    if getattr(args, "output", None):
        Path(args.output).write_text(text)
        Path(args.output).chmod(0o755)
        print(f"wrote {args.output}; submit with "
              f"{'sbatch' if args.scheduler == 'slurm' else 'qsub'} {args.output}")
    else:
        sys.stdout.write(text)
    return 0
