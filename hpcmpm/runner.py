"""The run loop: time-step choice, output and checkpoint schedule, signals, progress.

`run_command` / `restart_command` are what `hpcmpm run` and `hpcmpm restart` call. Every
decision that makes ranks branch (stop, write, checkpoint, rebalance) is agreed through a
collective first, so no rank is left waiting in a collective the others skipped.
"""

from __future__ import annotations

import logging
import math
import shlex
import signal
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .errors import (EXIT_CHECKPOINTED_ON_SIGNAL, HpcmpmError, InstabilityError,
                     OutputExistsError, SceneError)
from .parallel import Communicator, check_launch, make_domain
from .progress import Progress
from .signals import SignalFlag
from .simulation import Simulation

log = logging.getLogger(__name__)

# How far the stability bound may fall below the run's largest step (`Runner.check_collapse`).
DT_COLLAPSE = 1.0e-6


class CheckpointedOnSignal(HpcmpmError):
    """The run received SIGTERM/SIGUSR1, wrote a checkpoint and stopped (resume with
    `hpcmpm restart`): an expected event of a batch job, not an error."""

    exit_code = EXIT_CHECKPOINTED_ON_SIGNAL
    label = "stopped"


@dataclass
class RunOptions:
    out_dir: Path
    end_time: float
    quiet: bool = False
    checkpoint_every: int | None = None
    checkpoint_wall: float | None = None  # seconds of wall time between checkpoints
    checkpoint_keep: int = 2
    debug_checks: bool = False
    restart_chain: list[str] = field(default_factory=list)


def parse_wall_time(text: str | None) -> float | None:
    """``HH:MM:SS`` (or ``MM:SS`` or seconds) to seconds."""
    if text is None:
        return None
    try:
        parts = [float(x) for x in str(text).split(":")]
    except ValueError:
        raise SceneError(f"--checkpoint-wall: expected HH:MM:SS, got {text!r}") from None
    seconds = 0.0
    for part in parts:
        seconds = seconds * 60.0 + part
    if not math.isfinite(seconds) or seconds <= 0 or len(parts) > 3 or min(parts) < 0:
        raise SceneError(f"--checkpoint-wall: expected a positive HH:MM:SS, got {text!r}")
    return seconds


def frame_time(k: int, every: float, end_time: float) -> float:
    """``min(k * every, end_time)`` rounded to 15 significant digits: the time a reader means.

    In binary 33 * 0.1 is 3.3000000000000003, one ulp above the 3.3 the scene asks for; that
    number would land in every frame, checkpoint and ``particles.xdmf`` (which prints the
    shortest round-trip repr). 15 digits is below float64's 15.95, so the rounding never moves
    a time by more than an ulp or two, and frames stay distinct and increasing."""
    return min(float(f"{k * every:.15g}"), end_time)


class Runner:
    """Drives a `Simulation` to ``end_time`` with frames, checkpoints and progress."""

    def __init__(self, sim: Simulation, writer, options: RunOptions, frame_index: int = 0,
                 first_frame_written: bool = False, observer=None,
                 signal_flag: SignalFlag | None = None):
        self.sim = sim
        # Installed by the CLI at start-up, so a signal during imports or compilation is kept;
        # otherwise the run installs its own.
        self.signal_flag = signal_flag
        self.observer = observer  # called as observer(sim) after every step (tests, studies)
        self.domain = sim.domain
        self.writer = writer
        self.options = options
        self.frame_index = frame_index  # frames written so far
        self.first_frame_written = first_frame_written
        self.dt_warned = False
        self.last_dt = 0.0
        self.dt_peak = 0.0  # the largest step the stability bound has allowed so far
        every = sim.scene.output.every
        self.frame_every = every if every and every > 0 else options.end_time

    def restore_time_step_state(self, meta: dict) -> None:
        """The time-step state a checkpoint holds: the last dt and whether the fixed-dt
        warning was given (so a restarted run does not repeat it)."""
        self.last_dt = float(meta.get("last_dt", self.last_dt))
        self.dt_warned = bool(meta.get("dt_warned", self.dt_warned))
        self.dt_peak = float(meta.get("dt_peak", self.dt_peak))

    # -- schedule --------------------------------------------------------------------------
    def frame_time(self, k: int) -> float:
        """Simulated time of frame k: 0, every, 2 every, ..., and the end time."""
        return frame_time(k, self.frame_every, self.options.end_time)

    def next_frame_time(self, t: float) -> float:
        """The first output time after t: the next multiple of ``every``, or the end time.
        Counted from t, not from the frames written: a run that ended between two multiples
        wrote its end-time frame too, and its restart must still write the next multiple
        (the relative 1e-12 puts a t that landed on a multiple, up to round-off, past it)."""
        return self.frame_time(math.floor(t / self.frame_every * (1.0 + 1e-12)) + 1)

    def choose_dt(self) -> float:
        return self.step_within(self.sim.stable_dt())  # also the instability guard

    def step_within(self, stable: float) -> float:
        """The step to take under the stability bound ``stable`` (agreed by all ranks): the
        fixed dt where the scene sets one, capped by max_dt, checked for a collapse."""
        sim = self.sim
        fixed = sim.scene.dt
        if fixed is not None:
            if fixed > stable and not self.dt_warned:
                log.warning("fixed dt %.3g exceeds the CFL bound %.3g at step %d; "
                            "the run may become unstable", fixed, stable, sim.step_index)
                self.dt_warned = True
            stable = fixed
        if sim.scene.max_dt is not None:
            stable = min(stable, sim.scene.max_dt)
        if fixed is None:
            self.check_collapse(stable)
        return stable

    def check_collapse(self, dt: float) -> None:
        """Stops a run whose stability bound has fallen `DT_COLLAPSE` below the largest step
        it allowed before: a wave or particle speed that grew a million-fold is a blow-up
        with finite values, and the run would otherwise crawl on for ever. Measured (crash
        fuzz, seed 405): taylor_cu_3d with eos.gamma0 = 9.2e18 went from dt = 7.7e-8 to
        1.5e-22 in 300 steps and then took 65 000 steps without advancing t by 1e-11.
        Legitimate runs stay far inside the factor: a shock raises copper's wave speed a
        few times, and a semi-implicit step shrinks with the flow's speed, from at most
        cfl dx / c (or sqrt(cfl dx / |g|)) at rest. The ranks agree on dt, so they raise
        together."""
        sim = self.sim
        if math.isfinite(dt) and dt > self.dt_peak:
            self.dt_peak = dt
        if not dt < DT_COLLAPSE * self.dt_peak:
            return
        where = sim.fastest_signal()
        ratio = self.dt_peak / dt if dt > 0.0 else math.inf  # a wave speed beyond the floats
        raise InstabilityError(
            f"the time step collapsed at step {sim.step_index}, t={sim.time:.6g}: the "
            f"stability bound allows dt = {dt:.3g}, {ratio:.3g} times below the "
            f"largest step of this run ({self.dt_peak:.3g}); {where}. Hint: a material's "
            f"state has left the range of its model (check the equation-of-state and "
            f"hardening values of that material, e.g. eos.gamma0, and its moduli); a lower "
            f"simulation.cfl would not help.")

    # -- loop ------------------------------------------------------------------------------
    def run(self) -> dict:
        from .io.checkpoint import reached_end

        sim, opts = self.sim, self.options
        n_global = self.domain.sum(sim.particles.n)
        progress = Progress(opts.end_time, n_global, disabled=opts.quiet or self.domain.rank)
        progress.start(sim.time, sim.step_index)
        if self.domain.rank == 0:
            for material in sim.materials:      # what the scene's keys amount to here
                for line in material.notes():
                    log.info("%s", line)
        last_ckpt_wall = time.monotonic()
        if not self.first_frame_written:
            sim.assert_healthy()  # a scene whose initial state is broken writes no frame
            self.write_frame()
            self.first_frame_written = True
        with nullcontext(self.signal_flag) if self.signal_flag else SignalFlag() as flag:
            while not reached_end(sim.time, opts.end_time):
                # Agreed with the time step's health check (one allreduce for both).
                self.domain.stop_requested = flag.raised is not None
                dt = self.choose_dt()
                if self.domain.stop_agreed:
                    self.write_checkpoint()
                    progress.close()
                    raised = [s for s in self.domain.allgather(flag.raised) if s is not None]
                    raise CheckpointedOnSignal(
                        f"{signal.Signals(raised[0]).name} received: checkpoint written at "
                        f"step {sim.step_index}, t={sim.time:.6g} in {opts.out_dir}; continue "
                        f"with `hpcmpm restart {shlex.quote(str(self.latest_checkpoint_path))}`")
                if not sim.time + dt > sim.time:
                    raise InstabilityError(
                        f"the time step no longer advances the run at step {sim.step_index}, "
                        f"t={sim.time:.6g}: dt = {dt:.3g}. Hint: a wave speed, gravity or "
                        f"boundary speed beyond the floating-point range (check the materials' "
                        f"moduli and densities, simulation.gravity and the colliders' and "
                        f"prescribed sets' motion), or simulation.end_time too large for the "
                        f"step.")
                target = self.next_frame_time(sim.time)
                clipped = sim.time + dt >= target * (1 - 1e-12)
                if clipped and abs(target - sim.time - dt) > 1e-9 * dt:
                    # A gap that differs from dt by round-off only keeps dt's bits: a run
                    # that ends at a frame and its restart then step exactly like one run.
                    dt = target - sim.time
                sim.step(dt)
                self.last_dt = dt
                if clipped:
                    sim.time = target  # land exactly on the output time
                    sim.check_health()  # never write a broken state into a frame
                    self.write_frame()
                if opts.debug_checks:
                    self.check_particle_count(n_global)
                self.maybe_rebalance()
                if opts.checkpoint_every and sim.step_index % opts.checkpoint_every == 0:
                    self.write_checkpoint()
                if opts.checkpoint_wall is not None:
                    elapsed = self.domain.max(time.monotonic() - last_ckpt_wall)
                    if elapsed >= opts.checkpoint_wall:
                        self.write_checkpoint()
                        last_ckpt_wall = time.monotonic()
                if self.observer is not None:
                    self.observer(sim)
                progress.update(sim.time, sim.step_index, dt)
        progress.close()
        if self.writer is not None:
            self.write_checkpoint()
        return sim.diagnostics()

    def check_particle_count(self, expected: int) -> None:
        n = self.domain.sum(self.sim.particles.n)
        if n != expected:
            raise HpcmpmError(f"particle count changed at step {self.sim.step_index}: "
                              f"{expected} -> {n} (migration bug)")

    def maybe_rebalance(self) -> None:
        spec = self.sim.scene.parallel
        if self.domain.size > 1 and self.sim.step_index % spec.rebalance_every == 0:
            if self.domain.rebalance(self.sim.particles, spec.rebalance_threshold,
                                     self.sim.load_weights()):
                self.sim.request_sort()

    # -- output ----------------------------------------------------------------------------
    def write_frame(self) -> None:
        if self.writer is None:
            self.frame_index += 1
            return
        sim = self.sim
        with sim.timers("output"):
            diag = sim.diagnostics()
            attrs = {k: v for k, v in diag.items()}
            derived = {"tau": sim.kirchhoff_stress()} if "tau" in self.writer.fields else None
            self.writer.write(sim.particles, sim.time, sim.step_index, extra_attrs=attrs,
                              derived=derived)
        self.frame_index += 1

    @property
    def latest_checkpoint_path(self) -> str:
        return str(getattr(self, "_latest_ckpt", ""))

    def write_checkpoint(self) -> None:
        from .io.checkpoint import write_checkpoint

        sim, domain = self.sim, self.domain
        # Never a checkpoint of a blown-up state (a restart takes it), nor of one whose time
        # step has collapsed (`check_collapse`: the collapse shows in the state the step left;
        # a fixed dt cannot collapse, and its bound is not warned about before it is taken).
        speed = sim.assert_healthy()
        if sim.scene.dt is None:
            self.step_within(sim.integrator.stable_dt(sim, speed))
        meta = {
            "step": sim.step_index, "time": sim.time, "frame_index": self.frame_index,
            "last_dt": self.last_dt, "dt_warned": self.dt_warned, "dt_peak": self.dt_peak,
            "end_time": self.options.end_time, "scene_text": sim.scene.text,
            "scene_path": str(sim.scene.path), "boxes": domain.boxes.copy(),
            "n_ranks": domain.size, "hpcmpm_version": __version__,
            "restart_chain": list(self.options.restart_chain),
            "rank_counts": np.asarray(domain.allgather(sim.particles.n), dtype=np.int64),
            "needs_sort": np.asarray(domain.allgather(sim.needs_sort), dtype=np.int8),
        }
        with sim.timers("checkpoint"):
            # Side structures first (PD bonds): a particle checkpoint that exists has them.
            for extension in sim.extensions:
                if hasattr(extension, "write_checkpoint"):
                    extension.write_checkpoint(self.options.out_dir, sim.step_index,
                                               self.options.checkpoint_keep)
            self._latest_ckpt = write_checkpoint(self.options.out_dir, domain, sim.particles,
                                                 meta, keep=self.options.checkpoint_keep)


# -- commands --------------------------------------------------------------------------------
def load_scene_on_root(comm: Communicator, path: str, overrides) -> object:
    """Rank 0 validates, every rank gets the frozen scene or the same error."""
    from .scene import load_scene

    scene, error = None, None
    if comm.rank == 0:
        try:
            scene = load_scene(path, overrides)
        except SceneError as exc:
            error = exc
    scene, error = comm.bcast((scene, error))
    if error is not None:
        raise error
    return scene


def check_options(args) -> None:
    """The command-line values of ``run``/``restart`` through the scene's own checks (one line
    each, `SceneError`, exit 2): ``--end-time`` as ``simulation.end_time``, ``--checkpoint-every``
    as ``output.checkpoint_every``, ``--checkpoint-wall`` a positive wall time, ``--out`` a
    folder. Deterministic, so every rank raises the same error without a collective."""
    from .scene import CommandLineChecker

    c = CommandLineChecker()
    c.option("--end-time", getattr(args, "end_time", None), low=0.0)
    c.option("--checkpoint-every", getattr(args, "checkpoint_every", None), low=1,
             low_open=False, integer=True)
    try:
        parse_wall_time(getattr(args, "checkpoint_wall", None))
    except SceneError as exc:
        c.problems.extend(exc.problems)
    out = getattr(args, "out", None)
    if out is not None:
        c.problems.extend(output_dir_problems(Path(out)))
    c.raise_problems()


def output_dir_problems(out_dir: Path) -> list[str]:
    """Why ``out_dir`` cannot be an output folder (a file, or under a file), or nothing."""
    for path in (out_dir, *out_dir.parents):
        try:
            exists = path.exists()  # raises for a name too long, for one
        except OSError as exc:
            return [f"--out: cannot create {out_dir}: {exc.strerror or exc}"]
        if exists and not path.is_dir():
            what = "is" if path == out_dir else f"lies under {path}, which is"
            return [f"--out: {out_dir} {what} a file, not a folder"]
        if exists:
            break
    return []


def make_output_dir(comm: Communicator, out_dir: Path) -> None:
    """Rank 0 creates ``out_dir``; a failure is the same `SceneError` on every rank."""
    problem = None
    if comm.rank == 0:
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            problem = f"--out: cannot create {out_dir}: {exc.strerror or exc}"
    problem = comm.bcast(problem)
    if problem:
        raise SceneError(problem)


# What `hpcmpm render` and `hpcmpm plot` write into a run folder by default: pictures of the
# run's frames, which `--force` removes with the frames they show.
DERIVED_OUTPUT = ("render/render_[0-9]*.png", "render/render.mp4", "render/render.gif",
                  "render/render.webp", "diagnostics.csv", "diagnostics.png")


def other_runs_output(out_dir: Path) -> list[Path]:
    """The frames, checkpoints, XDMF and partial files of a run in ``out_dir``."""
    return [p for p in out_dir.glob("*") if p.suffix in (".h5", ".xdmf", ".tmp")] \
        if out_dir.is_dir() else []


def check_output_dir(comm: Communicator, out_dir: Path, force: bool) -> None:
    """A run never overwrites another run's output without ``--force``: the same
    `OutputExistsError` on every rank. Touches nothing, so it can come before the start-up
    checks that may still refuse the run (`prepare_output_dir` comes after them)."""
    problem = None
    if comm.rank == 0:
        existing = other_runs_output(out_dir)
        if existing and not force:
            problem = (f"{out_dir} already holds output of another run ({len(existing)} files); "
                       f"choose another --out or pass --force to replace it")
    problem = comm.bcast(problem)
    if problem:
        raise OutputExistsError(problem)


def prepare_output_dir(comm: Communicator, out_dir: Path, force: bool) -> None:
    """`check_output_dir`, then, with ``--force``, that run's frames, checkpoints, XDMF and
    the pictures made of them (`DERIVED_OUTPUT`) go, and the folder is made."""
    check_output_dir(comm, out_dir, force)
    if comm.rank == 0:
        existing = other_runs_output(out_dir)
        pictures = [p for pattern in DERIVED_OUTPUT for p in out_dir.glob(pattern)] \
            if existing else []
        for p in existing + pictures:
            p.unlink()
    make_output_dir(comm, out_dir)


def initial_particles(sim: Simulation) -> None:
    """Count, check the memory, sample this rank's share and decompose (`hpcmpm.startup`)."""
    from .startup import initial_particles as start

    start(sim)


def make_writer(sim: Simulation, out_dir: Path, restart_chain: list[str], frame_index: int = 0):
    from .io.frames import FrameWriter

    provenance = {"restart_chain": restart_chain, "n_ranks": sim.domain.size,
                  "hpcmpm_version": __version__, "scene_path": str(sim.scene.path)}
    # Step extensions add their own fields to frames (SPB-MPM: model, damage, EE).
    fields = list(sim.scene.output.fields)
    fields += [f for e in sim.extensions for f in getattr(e, "output_fields", ())
               if f not in fields]
    return FrameWriter(out_dir, sim.domain, sim.scene.text, sim.dim, fields, provenance,
                       first_frame=frame_index)


def report_done(comm: Communicator, out_dir: Path, diag: dict, wall: float, steps: int,
                n: int) -> None:
    if comm.rank:
        return
    xdmf = out_dir / "particles.xdmf"
    log.info("done: %d steps, %d particles in %.1f s (%.3g particle-steps/s)", steps, n, wall,
             n * steps / max(wall, 1e-9))
    log.info("mass %.6g, kinetic %.6g, elastic %.6g", diag["mass"], diag["kinetic_energy"],
             diag["elastic_energy"])
    print(f"output: {out_dir.resolve()}\n"
          f"open in ParaView: paraview {shlex.quote(str(xdmf.resolve()))}  (frames: "
          f"{out_dir}/frame_*.h5)")


def simulate(scene, end_time: float | None = None, observer=None, comm=None) -> Simulation:
    """Run ``scene`` in-process without writing anything; returns the finished simulation.

    For tests and studies: ``observer(sim)`` sees the state after every step."""
    comm = comm or Communicator()
    sim = Simulation(scene, make_domain(scene, comm))
    initial_particles(sim)
    options = RunOptions(out_dir=Path("."), end_time=float(end_time or scene.end_time),
                         quiet=True)
    Runner(sim, None, options, observer=observer).run()
    return sim


def check_end_time_frames(every: float, end_time: float | None) -> None:
    """``--end-time`` against the scene's output.every (`frame_count_problem`; the scene's
    own end time was checked with the scene): the same `SceneError` on every rank."""
    from .scene import frame_count_problem

    too_many = None if end_time is None else frame_count_problem(every, end_time)
    if too_many:
        raise SceneError(f"--end-time: output.every = {too_many}")


def run_command(args, signal_flag: SignalFlag | None = None) -> int:
    check_options(args)
    comm = Communicator()
    check_launch(comm)
    scene = load_scene_on_root(comm, args.scene, getattr(args, "set", None) or [])
    check_end_time_frames(scene.output.every, args.end_time)
    if getattr(args, "dry_run", False):
        from .startup import dry_run

        return dry_run(scene, comm)
    out_dir = Path(args.out) if args.out else Path("runs") / Path(args.scene).stem
    force = bool(getattr(args, "force", False))
    check_output_dir(comm, out_dir, force)
    domain = make_domain(scene, comm)
    domain.install_abort_hook()
    sim = Simulation(scene, domain)
    initial_particles(sim)
    # A run refused at start-up (memory, a broken initial state) leaves no folder behind,
    # and --force removes the other run's output only once this run can start.
    sim.assert_healthy()
    prepare_output_dir(comm, out_dir, force)
    options = RunOptions(
        out_dir=out_dir,
        end_time=float(scene.end_time if args.end_time is None else args.end_time),
        quiet=bool(args.quiet), checkpoint_every=args.checkpoint_every or
        scene.output.checkpoint_every, checkpoint_wall=parse_wall_time(args.checkpoint_wall),
        checkpoint_keep=scene.output.checkpoint_keep,
        debug_checks=bool(getattr(args, "debug_checks", False)),
        restart_chain=[str(Path(args.scene).resolve())])
    return execute(sim, options, comm, frame_index=0, first_frame_written=False,
                   signal_flag=signal_flag)


def execute(sim: Simulation, options: RunOptions, comm: Communicator, frame_index: int,
            first_frame_written: bool, signal_flag: SignalFlag | None = None,
            restored: dict | None = None) -> int:
    writer = make_writer(sim, options.out_dir, options.restart_chain, frame_index)
    runner = Runner(sim, writer, options, frame_index, first_frame_written,
                    signal_flag=signal_flag)
    if restored is not None:
        runner.restore_time_step_state(restored)
    start, step0 = time.perf_counter(), sim.step_index
    diag = runner.run()
    n = sim.domain.sum(sim.particles.n)
    report_done(comm, options.out_dir, diag, time.perf_counter() - start,
                sim.step_index - step0, n)
    if comm.rank == 0:
        log.info("phase times: %s", sim.timers.report())
    return 0


def restore_simulation(ckpt: str, comm: Communicator, end_time: float | None):
    """Rebuild the simulation held by checkpoint ``ckpt`` on the current rank count."""
    from .io.checkpoint import read_checkpoint
    from .scene import parse_scene
    from .state import ParticleSet

    fields, meta = read_checkpoint(ckpt, comm)  # reading needs the collective verbs only
    scene = parse_scene(meta["scene_text"], path=meta.get("scene_path", "<checkpoint>"))
    domain = make_domain(scene, comm)
    sim = Simulation(scene, domain)
    specs = dict(sim.particles.specs)
    sim.particles = ParticleSet(scene.dim, specs, capacity=len(fields["id"]))
    derived = set()
    if "J" in specs and "J" not in fields and "F" in fields:
        # Written before fluid-only scenes carried J alone: J = det F is their whole state.
        fields["J"] = np.linalg.det(fields["F"])
        derived = {"F"}
    mismatch = field_mismatch(Path(ckpt).name, set(fields) - derived, set(specs))
    if mismatch and comm.rank == 0:
        log.warning("%s", mismatch)
    sim.particles.append({k: v for k, v in fields.items() if k in specs})
    same_count = int(meta["n_ranks"]) == domain.size
    if same_count:
        domain.set_boxes(np.asarray(meta["boxes"]))
        domain.migrate(sim.particles)  # moves nothing: every rank got back its own rows
        pending = meta.get("needs_sort")
        sim.restore_order_state(True if pending is None else bool(pending[domain.rank]))
    else:
        domain.decompose(sim.particles, weights=sim.load_weights())
    sim.time = float(meta["time"])
    sim.step_index = int(meta["step"])
    for extension in sim.extensions:
        if hasattr(extension, "restore"):
            extension.restore(ckpt)  # side structures (PD bonds) of this checkpoint
    return sim, meta, end_time if end_time is not None else float(meta["end_time"])


def field_mismatch(name: str, stored: set[str], declared: set[str]) -> str | None:
    """One line when the checkpoint's particle fields and the ones this run declares differ
    (a checkpoint of another version of hpcmpm): what is dropped, what starts from defaults."""
    dropped, filled = sorted(stored - declared), sorted(declared - stored)
    parts = []
    if dropped:
        parts.append(f"drops checkpoint fields this run does not declare: {', '.join(dropped)}")
    if filled:
        parts.append(f"starts declared fields the checkpoint lacks from their defaults: "
                     f"{', '.join(filled)}")
    return f"restart from {name} {'; '.join(parts)}" if parts else None


def restart_command(args, signal_flag: SignalFlag | None = None) -> int:
    check_options(args)
    comm = Communicator()
    check_launch(comm)
    ckpt = checkpoint_to_restart(Path(args.checkpoint), comm)
    sim, meta, end_time = restore_simulation(str(ckpt), comm, args.end_time)
    check_end_time_frames(sim.scene.output.every, args.end_time)
    from .io.checkpoint import reached_end

    if reached_end(sim.time, end_time):
        return nothing_to_run(comm, ckpt, sim.time, end_time, args.end_time is not None)
    sim.domain.install_abort_hook()
    out_dir = Path(args.out) if args.out else ckpt.parent
    if args.out and out_dir.resolve() != ckpt.parent.resolve():
        # Another folder: like `run`, never mix into another run's output without --force
        # (the continued series would sit beside the other run's frames and XDMF entries).
        prepare_output_dir(comm, out_dir, bool(getattr(args, "force", False)))
    elif args.out:
        make_output_dir(comm, out_dir)
    chain = list(meta.get("restart_chain", [])) + [str(ckpt.resolve())]
    options = RunOptions(out_dir=out_dir, end_time=end_time, quiet=bool(args.quiet),
                         checkpoint_keep=sim.scene.output.checkpoint_keep,
                         checkpoint_every=getattr(args, "checkpoint_every", None)
                         or sim.scene.output.checkpoint_every,
                         checkpoint_wall=parse_wall_time(getattr(args, "checkpoint_wall", None)),
                         debug_checks=bool(getattr(args, "debug_checks", False)),
                         restart_chain=chain)
    runner_frames = int(meta["frame_index"])
    if comm.rank == 0 and out_dir.resolve() == ckpt.parent.resolve():
        later = later_output(out_dir, runner_frames, int(meta["step"]), ckpt, end_time)
        if later:
            log.warning("%s", later)
    return execute(sim, options, comm, frame_index=runner_frames, first_frame_written=True,
                   signal_flag=signal_flag, restored=meta)


def later_output(out_dir: Path, frame_index: int, step: int, ckpt: Path,
                 end_time: float) -> str | None:
    """One line when the folder a restart continues in already holds output from beyond its
    checkpoint (a restart from an older checkpoint than the newest): those frames and
    checkpoints are replaced only where the restart writes the same names, so a restart that
    ends earlier leaves them in the series (`particles.xdmf`, `hpcmpm info`) after its own."""
    from .io.checkpoint import CKPT_PATTERN
    from .io.xdmf import FRAME_PATTERN

    frames, ckpts = [], []
    for path in out_dir.iterdir():
        if (m := FRAME_PATTERN.match(path.name)) and int(m.group(1)) >= frame_index:
            frames.append(path.name)
        elif (m := CKPT_PATTERN.match(path.name)) and int(m.group(1)) > step:
            ckpts.append(path.name)
    if not frames and not ckpts:
        return None
    what = []
    if frames:
        what.append(f"{len(frames)} frame(s) ({min(frames)} .. {max(frames)})")
    if ckpts:
        what.append(f"{len(ckpts)} checkpoint(s) ({min(ckpts)} .. {max(ckpts)})")
    return (f"warning: {out_dir} already holds {' and '.join(what)} from beyond {ckpt.name}: "
            f"the restart (to t={end_time:g}) replaces the files it writes under the same "
            f"names; those it does not reach stay in the series, and `hpcmpm info` describes "
            f"the newest checkpoint. To keep the two apart, restart with --out NEW_FOLDER")


def checkpoint_to_restart(path: Path, comm: Communicator) -> Path:
    """``path`` itself, or for a run folder its newest checkpoint (`latest_checkpoint`, chosen
    on rank 0 so that every rank restarts from the same file)."""
    if not path.is_dir():
        return path
    from .errors import CheckpointError
    from .io import latest_checkpoint

    newest = comm.bcast(latest_checkpoint(path) if comm.rank == 0 else None)
    if newest is None:
        raise CheckpointError(f"{path}: no checkpoint (ckpt_SSSSSSSSS.h5) in this folder")
    return Path(newest)


def nothing_to_run(comm: Communicator, ckpt: Path, time_now: float, end_time: float,
                   given: bool) -> int:
    """A restart whose checkpoint is at or past the end time runs no step and writes nothing:
    an explicit ``--end-time`` that is not later is an argument error (exit 2); a checkpoint at
    its run's own end says so and exits 0."""
    if given:
        raise SceneError(f"--end-time: must be later than the checkpoint's time t={time_now:.9g}"
                         f" ({ckpt.name}), got {end_time:g}")
    if comm.rank == 0:
        print(f"hpcmpm: nothing to run: {ckpt} is at t={time_now:.9g}, the end time of its run; "
              f"nothing was computed or written (continue further with --end-time T)")
    return 0
