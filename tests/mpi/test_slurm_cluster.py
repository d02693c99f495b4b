"""The script `hpcmpm jobscript --scheduler slurm` renders, submitted to a real SLURM (one node on
localhost: munged, slurmctld and slurmd started by the fixture from a private configuration,
with free ports and state under tmp, so nothing of the machine's own set-up is touched).

- a 2-rank run: one 2-rank world (frames say n_ranks = 2), "output:" once, exit 0;
- a run whose wall time (1 minute) ends first: SLURM's own USR1, the checkpoint, exit 75, the
  requeue and the resume from that checkpoint happen for real;
- plain `srun` on a cluster whose MpiDefault is none: 2 separate 1-rank runs, refused at
  start-up with one line, exit 2, nothing written.

A healthy run takes 40-80 s, most of it SLURM's own 30 s time-limit cycle; the waits are
minutes, for a loaded machine whose numba cache is cold.

Needs root and Debian's slurmctld, slurmd, slurm-client and munge (scripts/test.sh installs them
where apt-get allows); skipped with the reason elsewhere.
"""

from __future__ import annotations

import os
import random
import re
import shlex
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from hpcmpm import cli
from hpcmpm.io.frames import read_frame

ROOT = Path(__file__).resolve().parents[2]
DAEMONS = ("munged", "slurmctld", "slurmd", "sbatch", "scontrol", "scancel")


def _missing() -> str | None:
    if os.environ.get("PMI_SIZE") or os.environ.get("HPCMPM_MPI_CHILD"):
        return "starts its own cluster; not under mpiexec"
    if os.geteuid() != 0:
        return "a private SLURM needs root (slurmd runs jobs as their user)"
    absent = [d for d in DAEMONS if shutil.which(d) is None and
              not Path(f"/usr/sbin/{d}").exists()]
    if absent:
        return (f"SLURM is not installed ({', '.join(absent)} missing; scripts/test.sh installs "
                f"slurmctld slurmd slurm-client munge where root and apt-get allow)")
    return None


pytestmark = [pytest.mark.needs_tool,
              pytest.mark.skipif(_missing() is not None, reason=_missing() or "")]


def _exe(name: str) -> str:
    return shutil.which(name) or f"/usr/sbin/{name}"


def _signal(pid: int, sig: int) -> bool:
    """Send ``sig`` to ``pid``; whether it was alive."""
    try:
        os.kill(pid, sig)
        return True
    except ProcessLookupError:
        return False


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Cluster:
    """A one-node SLURM on localhost, configured and run from ``folder``; the daemons run in
    the foreground as children of this process, so stopping them needs no pid file."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.node = socket.gethostname().split(".")[0]
        self.conf = folder / "slurm.conf"
        self.env = dict(os.environ, SLURM_CONF=str(self.conf))
        self.daemons: list[subprocess.Popen] = []
        self.jobs: list[int] = []

    def _daemon(self, *cmd: str) -> subprocess.Popen:
        log = open(self.folder / f"{Path(cmd[0]).name}.out", "a")
        self.daemons.append(subprocess.Popen(cmd, env=self.env, stdout=log,
                                             stderr=subprocess.STDOUT))
        return self.daemons[-1]

    def start(self) -> None:
        f = self.folder
        (f / "state").mkdir()
        (f / "spool").mkdir()
        key = f / "munge.key"
        key.write_bytes(os.urandom(128))
        key.chmod(0o600)
        self._daemon(_exe("munged"), "--foreground", "--force", f"--socket={f}/munge.sock",
                     f"--key-file={key}", f"--pid-file={f}/munged.pid",
                     f"--log-file={f}/munged.log", f"--seed-file={f}/munged.seed")
        deadline = time.time() + 120  # seconds on an idle machine; minutes on a loaded one
        while not (f / "munge.sock").exists() and time.time() < deadline:
            time.sleep(0.1)
        for _ in range(3):  # a free port can be taken by another process before slurmctld binds
            self.write_conf()
            controller = self._daemon(_exe("slurmctld"), "-D")
            node = self._daemon(_exe("slurmd"), "-D", "-N", self.node)
            while time.time() < deadline and controller.poll() is None:
                out = self.scontrol("show", "node", self.node, check=False)
                if re.search(r"State=IDLE", out):
                    return
                time.sleep(0.5)
            for proc in (node, controller):
                proc.terminate()
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            self.daemons = self.daemons[:-2]
        raise RuntimeError(f"the SLURM node did not come up:\n"
                           f"{(f / 'slurmctld.log').read_text()[-3000:]}")

    def write_conf(self) -> None:
        f = self.folder
        # CPUs=6 on a smaller machine (config_overrides): the three jobs run side by side.
        # cred_expire: a requeued job waits that long (+1 s) before it may start again (its old
        # credential must expire first; forcing StartTime=now instead was refused at random
        # with "Job credential revoked"); the default 120 s would dominate the test.
        # FirstJobId: MPICH names its shared-memory segment after the PMI job id ("2.0"), so
        # job ids that repeat across clusters on one host (a stale segment of an earlier
        # cluster's job 2) break MPI_Init; each cluster starts its ids somewhere else.
        self.conf.write_text(f"""
ClusterName=hpcmpm{os.getpid()}
FirstJobId={random.randint(10**6, 6 * 10**7)}
SlurmctldHost={self.node}(127.0.0.1)
SlurmctldPort={_free_port()}
SlurmdPort={_free_port()}
AuthType=auth/munge
AuthInfo=socket={f}/munge.sock,cred_expire=10
CredType=cred/munge
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SlurmUser=root
SlurmdUser=root
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
StateSaveLocation={f}/state
SlurmdSpoolDir={f}/spool
SlurmctldPidFile={f}/slurmctld.pid
SlurmdPidFile={f}/slurmd.pid
SlurmctldLogFile={f}/slurmctld.log
SlurmdLogFile={f}/slurmd.log
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
ReturnToService=2
KillWait=5
SlurmdParameters=config_overrides
SchedulerParameters=sched_interval=1
NodeName={self.node} NodeAddr=127.0.0.1 CPUs=6 RealMemory=1000 State=UNKNOWN
PartitionName=debug Nodes={self.node} Default=YES MaxTime=INFINITE State=UP
""")

    def stop(self) -> None:
        """Cancel our jobs, wait for their processes to end (slurmstepd outlives slurmd), then
        stop the daemons this fixture started."""
        for job_id in self.jobs:
            subprocess.run([_exe("scancel"), str(job_id)], env=self.env, timeout=30)
        deadline = time.time() + 60
        while time.time() < deadline and any(self.steps(j) for j in self.jobs):
            time.sleep(0.5)
        for proc in reversed(self.daemons):
            proc.terminate()
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def steps(self, job_id: int) -> bool:
        """Whether job ``job_id`` still has a running step or batch script."""
        info = self.job(job_id)
        return info.get("JobState") not in (None, "COMPLETED", "FAILED", "CANCELLED",
                                             "TIMEOUT", "PENDING") or \
            bool(self.scontrol("listpids", str(job_id), check=False).strip().count("\n"))

    def scontrol(self, *args: str, check: bool = True) -> str:
        proc = subprocess.run([_exe("scontrol"), *args], env=self.env, capture_output=True,
                              text=True, timeout=30)
        if check and proc.returncode:
            raise RuntimeError(f"scontrol {' '.join(args)}: {proc.stderr}")
        return proc.stdout

    def submit(self, script: Path) -> int:
        proc = subprocess.run([_exe("sbatch"), "--parsable", str(script)], env=self.env,
                              capture_output=True, text=True, timeout=30, cwd=self.folder,
                              check=True)
        self.jobs.append(int(proc.stdout.strip().split(";")[0]))
        return self.jobs[-1]

    def job(self, job_id: int) -> dict[str, str]:
        out = self.scontrol("show", "job", "-o", str(job_id), check=False)
        return dict(re.findall(r"(\w+)=(\S*)", out))


@pytest.fixture(scope="module")
def cluster():
    # A folder of its own, not pytest's rotating tmp: the daemons keep state there until the
    # very end.
    folder = Path(tempfile.mkdtemp(prefix="hpcmpm-slurm-"))
    c = Cluster(folder)
    try:
        c.start()
        yield c
    finally:
        c.stop()
        if not os.environ.get("HPCMPM_KEEP_SLURM"):
            shutil.rmtree(folder, ignore_errors=True)


def render(cluster: Cluster, name: str, time_limit: str, *extra: str, mpi: str = "pmi2",
           scene: Path = ROOT / "inputs" / "disks_2d.toml") -> Path:
    """`hpcmpm jobscript` run in the cluster's folder (where the job is submitted from), its
    options after the scene as well as before."""
    script = cluster.folder / f"{name.replace(' ', '_')}.sh"
    here = os.getcwd()
    os.chdir(cluster.folder)
    try:
        code = cli.main(["jobscript", "--scheduler", "slurm", "--nodes", "1",
                         "--ranks-per-node", "2", "--time", time_limit, "--mpi", mpi,
                         "--out", f"runs/{name}", str(scene),
                         "--activate", f". {ROOT}/scripts/env.sh", "-o", str(script), "--",
                         *extra])
    finally:
        os.chdir(here)
    assert code == 0
    return script


def wait_for(what: str, condition, timeout: float, cluster: Cluster, job_id: int):
    deadline = time.time() + timeout
    while time.time() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.5)
    raise AssertionError(f"job {job_id}: {what} within {timeout:.0f} s; job: "
                         f"{cluster.job(job_id)}; log:\n{log_of(cluster, job_id)[-3000:]}")


def log_of(cluster: Cluster, job_id: int) -> str:
    logs = list(cluster.folder.glob(f"runs/*/slurm-{job_id}.out"))
    return logs[0].read_text() if logs else "(no log)"


def frames(folder: Path) -> list[Path]:
    return sorted(folder.glob("frame_*.h5"))


def test_rendered_script_on_a_real_slurm(cluster):
    runs = cluster.folder / "runs"
    # The requeued job's scene and output folder have spaces in their names (its log path in
    # the #SBATCH line, the job name, the shell's variables), and the extra arguments that the
    # restart must be given again follow it to the requeued job's `hpcmpm restart`.
    spaced = cluster.folder / "disks copy.toml"
    shutil.copy(ROOT / "inputs" / "disks_2d.toml", spaced)
    jobs = {
        # Never finishes by itself: the 1-minute wall time ends it (the long pole: first).
        "requeue": cluster.submit(render(cluster, "re queue", "00:01:00", "--end-time", "1000",
                                         "--checkpoint-every", "100000", "--debug-checks",
                                         scene=spaced)),
        # Finishes: 2 ranks, 0.05 of simulated time (8 steps).
        "complete": cluster.submit(render(cluster, "complete", "00:05:00",
                                          "--end-time", "0.05")),
        # Plain srun, MpiDefault=none: two unconnected copies.
        "singletons": cluster.submit(render(cluster, "singletons", "00:05:00",
                                            "--end-time", "0.05", mpi="default")),
    }

    def finished(job_id):
        return lambda: cluster.job(job_id).get("JobState") in ("COMPLETED", "FAILED")

    # -- the singleton launch is refused at start-up, once, before anything is written --------
    job = jobs["singletons"]
    wait_for("finish", finished(job), 180, cluster, job)
    info, log = cluster.job(job), log_of(cluster, job)
    # The copies exit with 2; srun's --kill-on-bad-exit then stops a copy still starting up,
    # so the job's own code is 2 or that copy's signal (143, 137): never 0.
    assert info["JobState"] == "FAILED" and info["ExitCode"] != "0:0", (info, log)
    assert re.search(r"task \d+: Exited with exit code 2", log), log
    told = [l for l in log.splitlines()
            if l.startswith(("hpcmpm: error:", "hpcmpm: stopped:"))]
    assert len(told) == 1 and told[0].startswith(
        "hpcmpm: error: launched as 2 separate 1-rank runs: srun started 2 tasks"), log
    assert not frames(runs / "singletons")

    # -- a 2-rank run with --mpi=pmi2 is one 2-rank world -------------------------------------
    job = jobs["complete"]
    wait_for("finish", finished(job), 240, cluster, job)
    info, log = cluster.job(job), log_of(cluster, job)
    assert info["ExitCode"] == "0:0", (info, log)
    assert log.count("output: ") == 1, log
    written = frames(runs / "complete")
    assert len(written) >= 2
    _, attrs = read_frame(written[-1])
    assert attrs["n_ranks"] == 2 and attrs["time"] == pytest.approx(0.05)

    # -- the wall time: SLURM's USR1, checkpoint, exit 75, requeue, resume ---------------------
    job = jobs["requeue"]
    # SLURM checks time limits every 30 s and sends the warning up to a minute early: with a
    # 1-minute limit and a 10 s margin, within the first 50 s. The requeued job then waits
    # cred_expire + 1 = 11 s (slurm.conf above) and starts again.
    wait_for("requeue after the wall-time signal",
             lambda: int(cluster.job(job).get("Restarts", "0")) >= 1, 240, cluster, job)
    log = log_of(cluster, job)
    stopped = [l for l in log.splitlines() if l.startswith("hpcmpm: stopped: SIGUSR1")]
    assert len(stopped) == 1, log  # once per job, labelled as the expected event it is
    assert f"requeueing job {job}" in log  # the script saw exit code 75 and requeued
    assert cluster.job(job)["JobName"] == "disks_copy"
    # The command as a shell takes it: the folder's space is quoted.
    ckpt = shlex.split(re.search(r"hpcmpm restart (.+?)`", stopped[0]).group(1))[0]
    ckpt = (cluster.folder / ckpt) if not ckpt.startswith("/") else Path(ckpt)
    n_before = len(frames(runs / "re queue"))

    def resumed():
        later = frames(runs / "re queue")
        if len(later) <= n_before:
            return None
        _, attrs = read_frame(later[-1])
        return attrs

    attrs = wait_for("a frame written after the resume", resumed, 180, cluster, job)
    assert attrs["n_ranks"] == 2
    assert str(ckpt.name) in attrs["restart_chain"], attrs["restart_chain"]

    # -- scancel: the ranks still checkpoint, but a cancelled job is not requeued --------------
    subprocess.run([_exe("scancel"), str(job)], env=cluster.env, timeout=30, check=True)
    wait_for("end after scancel", lambda: not cluster.steps(job), 60, cluster, job)
    info, log = cluster.job(job), log_of(cluster, job)
    # The batch shell either sees TERM and does not requeue, or is killed first (KillWait).
    assert info["JobState"] == "CANCELLED" and info["Restarts"] == "1", (info, log)
    assert log.count("requeueing job") == 1, log
