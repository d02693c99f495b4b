"""`hpcmpm jobscript`: render a SLURM or PBS script from the templates in ``jobs/``.

The rendered script activates the environment, launches the ranks, forwards the scheduler's
early-warning signal so the run checkpoints before the wall time, and resumes from the newest
checkpoint when the job is requeued or resubmitted.
"""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path
from string import Template

from .errors import EXIT_CHECKPOINTED_ON_SIGNAL, HpcmpmError

SCHEDULERS = ("slurm", "pbs")
# Seconds before the wall time at which the run is told to checkpoint: enough for one step
# plus a checkpoint write of a large run.
SIGNAL_MARGIN = 300
# ... and at least this many (a tenth of the wall time in between).
MIN_SIGNAL_MARGIN = 10
# srun's MPI plugin: PMI-2 gives MPICH (the PyPI wheel too) its ranks; see jobs/slurm.sh.in.
DEFAULT_SRUN_MPI = "pmi2"
# `hpcmpm run` options that a requeued job's `hpcmpm restart` must be given again (the rest of
# the run's arguments are in the checkpoint: the scene with its --set values, the end time).
RESTART_OPTIONS = ("--checkpoint-every", "--checkpoint-wall")
RESTART_FLAGS = ("--debug-checks",)
# The job's log in its output folder (the scheduler opens it before the script runs).
LOG_NAMES = {"slurm": "slurm-%j.out", "pbs": "pbs.out"}


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
    seconds = values[0] * 3600 + values[1] * 60 + values[2]
    if seconds <= MIN_SIGNAL_MARGIN:
        # 0 is no limit to SLURM and none at all to PBS; either way the checkpoint signal,
        # due MIN_SIGNAL_MARGIN s before the end, would come at or before the start.
        raise JobScriptError(f"--time {text}: the run is told to checkpoint "
                             f"{MIN_SIGNAL_MARGIN} s before the wall time; give more than "
                             f"{MIN_SIGNAL_MARGIN} s")
    return seconds


def render(scheduler: str, scene: str, nodes: int, ranks_per_node: int, walltime: str,
           out_dir: str | None = None, activate: str | None = None,
           extra_args: list[str] | None = None, script_path: str = "",
           srun_mpi: str = DEFAULT_SRUN_MPI) -> str:
    """The job script's text (no side effects). ``script_path``: where the script is saved, so
    a PBS job resubmits that file (empty: the copy PBS runs). ``srun_mpi``: srun's ``--mpi``
    plugin (``"default"``: no option, the cluster's MpiDefault)."""
    if scheduler not in SCHEDULERS:
        raise JobScriptError(f"--scheduler: must be one of {', '.join(SCHEDULERS)}, got {scheduler!r}")
    if nodes < 1 or ranks_per_node < 1:
        raise JobScriptError("--nodes and --ranks-per-node must be >= 1")
    if not srun_mpi or not all(ch.isalnum() or ch in "_-." for ch in srun_mpi):
        raise JobScriptError(f"--mpi: expected an srun MPI plugin name such as pmi2, pmix or "
                             f"default, got {srun_mpi!r}")
    seconds = parse_walltime(walltime)
    margin = min(SIGNAL_MARGIN, max(seconds // 10, MIN_SIGNAL_MARGIN))
    out_dir = default_out_dir(scene, out_dir)
    log = directive_path(scheduler, out_dir)

    def words(args):
        return "".join(" " + shlex.quote(a) for a in args)

    mapping = {
        "job_name": job_name(scene), "nodes": nodes, "ranks_per_node": ranks_per_node,
        "walltime": walltime, "walltime_seconds": seconds, "signal_margin": margin,
        "exit_code": EXIT_CHECKPOINTED_ON_SIGNAL, "scene": shlex.quote(scene),
        "out_dir": shlex.quote(out_dir), "log": log,
        "activate": activate or f"source {shlex.quote(str(Path(sys.prefix) / 'bin' / 'activate'))}",
        "extra_args": words(extra_args or []),
        "restart_args": words(restart_arguments(extra_args or [])),
        "script_path": shlex.quote(script_path),
        "srun_mpi": "" if srun_mpi == "default" else f" --mpi={srun_mpi}",
    }
    return Template(template_path(scheduler).read_text(encoding="utf-8")).safe_substitute(mapping)


def job_name(scene: str) -> str:
    """The scene's file stem as a job name the schedulers take whole: runs of characters other
    than letters, digits, ``_``, ``.`` and ``-`` (a space would end a directive's value) become
    ``_``, and a name not starting with a letter gets ``j`` in front (PBS requires one)."""
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(scene).stem).strip("_") or "hpcmpm"
    return name if name[0].isalpha() else "j" + name


def directive_path(scheduler: str, out_dir: str) -> str:
    """The job log's path in ``out_dir`` as a directive's value. SLURM reads a double-quoted
    directive value whole (a space inside it included); PBS directives take no quoting that
    every PBS honours, so a folder with a space or a quote is refused there, as is a double
    quote, a backslash or a new line for SLURM."""
    if scheduler == "pbs" and re.search(r"[\s\"'\\]", out_dir):
        raise JobScriptError(f"--out: {out_dir!r}: a PBS job's log path (#PBS -o) cannot hold a "
                             f"space or a quote; pass an --out folder without one")
    if re.search(r"[\"\\\n]", out_dir):
        raise JobScriptError(f"--out: {out_dir!r}: a job's log path cannot hold a double quote, "
                             f"a backslash or a new line; pass another --out folder")
    path = f"{out_dir}/{LOG_NAMES[scheduler]}"
    return f'"{path}"' if scheduler == "slurm" else path


def restart_arguments(extra_args: list[str]) -> list[str]:
    """The extra `hpcmpm run` arguments that the requeued job's `hpcmpm restart` needs too
    (`RESTART_OPTIONS` with their values, `RESTART_FLAGS`), in their order."""
    kept, i = [], 0
    while i < len(extra_args):
        a = extra_args[i]
        if a in RESTART_OPTIONS and i + 1 < len(extra_args):
            kept += extra_args[i:i + 2]
            i += 2
            continue
        if a in RESTART_FLAGS or a.split("=", 1)[0] in RESTART_OPTIONS:
            kept.append(a)
        i += 1
    return kept


def default_out_dir(scene: str, out_dir: str | None) -> str:
    return out_dir or f"runs/{Path(scene).stem}"


def check_run_arguments(scene: str, extra_args: list[str], parser) -> None:
    """What the job will run, checked now rather than after a wait in the queue: the scene
    (with the ``--set`` values among ``extra_args``) validates and the extra ``hpcmpm run``
    arguments parse (by ``parser``, the command line's) and pass its checks."""
    from .runner import check_options
    from .scene import load_scene

    try:
        run_args = parser.parse_args(["run", scene, *extra_args])
    except SystemExit as exc:  # argparse printed the usage line and what is wrong
        raise JobScriptError(f"extra `hpcmpm run` arguments {extra_args}: not accepted "
                             f"(see above)") from exc
    load_scene(scene, run_args.set or [])
    check_options(run_args)


def jobscript_command(args, parser) -> int:
    """`hpcmpm jobscript`: ``parser`` is the command line's, which checks the run's own
    arguments (`check_run_arguments`)."""
    extra = list(getattr(args, "extra", None) or [])
    check_run_arguments(args.scene, extra, parser)
    # The scripts run quietly already (a batch log has no use for a progress bar).
    extra = [a for a in extra if a != "--quiet"]
    output = getattr(args, "output", None)
    text = render(args.scheduler, args.scene, args.nodes, args.ranks_per_node, args.time,
                  out_dir=getattr(args, "out", None), activate=getattr(args, "activate", None),
                  extra_args=extra, script_path=str(Path(output).resolve()) if output else "",
                  srun_mpi=getattr(args, "mpi", None) or DEFAULT_SRUN_MPI)
    # The scheduler opens the job's log in the output folder before the script runs.
    log_dir = Path(default_out_dir(args.scene, getattr(args, "out", None)))
    log_dir.mkdir(parents=True, exist_ok=True)
    if output:
        Path(output).write_text(text, encoding="utf-8")
        Path(output).chmod(0o755)
        print(f"wrote {output} (created {log_dir}/ for its log); submit it from {Path.cwd()} "
              f"(the relative paths in it start there): "
              f"{'sbatch' if args.scheduler == 'slurm' else 'qsub'} {output}")
    else:
        sys.stdout.write(text)
        print(f"hpcmpm: created {log_dir}/ for the job's log; submit the script from "
              f"{Path.cwd()} (the relative paths in it start there)", file=sys.stderr)
    return 0
