"""SPB-MPM through the engine (003 ch. 6, issue 11): the patch test that picks the default
coupling, the stress at the first conversion, momentum through conversions."""

from pathlib import Path

import numpy as np
import pytest

from hpcmpm.parallel import Communicator
from hpcmpm.runner import Runner, RunOptions, initial_particles, make_domain
from hpcmpm.scene import load_scene, parse_scene
from hpcmpm.simulation import Simulation

L = 25.0


def build(scene, convert_all=False):
    sim = Simulation(scene, make_domain(scene, Communicator()))
    initial_particles(sim)
    if convert_all:
        sim.extensions[0].convert_all = True
    return sim


def run(sim, end, observe):
    Runner(sim, None, RunOptions(out_dir=Path("."), end_time=end, quiet=True),
           observer=observe).run()


def bar_period(coupling=None, cells=50, horizon=3.015, clamp="sticky_walls"):
    """First-mode period of the round-1 bar (inputs/bar_2d.toml) from the zero crossings of
    v_cm; with a coupling, every particle is PD from the first step (the issue's "G_EE = 0",
    which a scene cannot ask for) and no bond breaks (bond_energy = inf)."""
    sets = [f"simulation.dx={L / cells}", "simulation.end_time=8.0"]
    if coupling:
        sets.append('materials.0.failure={model="spb", grid_energy=1.0, bond_energy=inf, '
                    f'coupling="{coupling}", horizon={horizon}, clamp="{clamp}"}}')
    sim = build(load_scene("inputs/bar_2d.toml", sets), convert_all=bool(coupling))
    history = []

    def observe(sim):
        p = sim.particles
        history.append((sim.time, (p["mass"] * p["v"][:, 0]).sum() / p["mass"].sum()))

    run(sim, 8.0, observe)
    if coupling:
        assert sim.extensions[0].pd_global == sim.particles.n
        assert sim.extensions[0].broken == 0
    t, v = np.array(history).T
    i = np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:]))[:2]
    zeros = t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])
    return 2 * (zeros[1] - zeros[0])


def test_patch_test_picks_the_exclusive_coupling():
    """Measured (50 cells, delta = 3.015 spacings = 1.5 dx): MPM alone 10.036; exclusive
    10.003 (-0.33 %; -0.34 % and -0.32 % at delta = 2.015 and 4.015 spacings, -0.17 % at
    100 cells, where MPM is 10.018: the PD bar is the closer to the exact 10); additive 7.079
    (-29.5 %, the doubled stiffness of Alg. 3 as printed). Without the clamp at the sticky
    end (clamp = "none") exclusive is 10.344 (+3.1 %): the wall holds PD particles only
    through the grid while their cut families pull them into the bar (docs/studies.md, SPB
    patch test)."""
    mpm = bar_period()
    exclusive = bar_period("exclusive")
    additive = bar_period("additive")
    err = {k: abs(T - mpm) / mpm for k, T in (("exclusive", exclusive), ("additive", additive))}
    print(f"bar periods: MPM {mpm:.4f}, exclusive {exclusive:.4f} ({exclusive / mpm - 1:+.2%}),"
          f" additive {additive:.4f} ({additive / mpm - 1:+.2%})")
    from hpcmpm.materials.failure import DEFAULT_COUPLING
    assert DEFAULT_COUPLING == min(err, key=err.get) == "exclusive"
    # The bar: the period within 2 % of MPM alone with the default coupling.
    assert err["exclusive"] < 0.02
    # Additive is about sqrt(2) too short: both the MPM stress and the bonds carry the load.
    assert additive == pytest.approx(mpm / np.sqrt(2), rel=0.03)
    # The clamp is what meets it: without, the cut families at the wall soften the bar.
    unclamped = bar_period("exclusive", clamp="none")
    assert unclamped / mpm - 1 > 0.025


def stretched_bar(nu, extra=()):
    """inputs/spb_stretched_bar_2d.toml at dx = 0.014, G_EE = l0 sigma_c^2 for that dx."""
    sigma_c = 400.0
    l0 = 3.015 * 0.007
    return load_scene("inputs/spb_stretched_bar_2d.toml",
                      ["simulation.dx=0.014", f"materials.0.nu={nu}",
                       f"materials.0.failure.grid_energy={l0 * sigma_c ** 2}",
                       *extra]), sigma_c


def test_first_conversion_at_the_critical_stress():
    """The bar stretched slowly (0.1 m/s per end) first converts when its tensile stress
    reaches sigma_c = sqrt(G_EE / l0). nu = 0, so the clamps add no stress concentration and
    the bar is in uniaxial stress; stresses come from the material's own kernel
    (Simulation.kirchhoff_stress / det F), not from the SPB code. EE_p is a history maximum,
    and each pull launches a stress wave of amplitude rho c v (c = 100, 10 = 2.5 % of sigma_c),
    so the stress oscillates about its mean by up to 2 rho c v where the two waves meet: the
    converting particles convert when their largest stress so far reaches sigma_c (measured
    +0.11 %); their stress at that step is below it by the oscillation (measured -5.2 %). At
    dx = 0.028 (3.5 cells across) the same gives -1.4 % and -9.4 %: too coarse for this bound."""
    scene, sigma_c = stretched_bar(0.0, ["simulation.end_time=0.2",
                                         "prescribed.0.velocity=[0.0, -0.1]",
                                         "prescribed.1.velocity=[0.0, 0.1]"])
    sim = build(scene)
    found = {}
    peak = np.zeros(sim.particles.n)

    def observe(sim):
        if found:
            return
        p = sim.particles
        order = np.argsort(p["id"])          # peak is kept by id: rows move with sorts
        sigma = (sim.kirchhoff_stress()[:, 1, 1] / np.linalg.det(p["F"]))[order]
        np.maximum(peak, sigma, out=peak)
        if not sim.extensions[0].pd_global:
            return
        pd = (p["model"] == 1)[order]
        found.update(t=sim.time, now=sigma[pd].mean(), peak=peak[pd].mean(), n=int(pd.sum()))

    run(sim, 0.2, observe)
    err_now, err_peak = found["now"] / sigma_c - 1, found["peak"] / sigma_c - 1
    print(f"first conversion at t = {found['t']:.4f}: {found['n']} particles, sigma now "
          f"{found['now']:.2f} ({err_now:+.2%}), largest so far {found['peak']:.2f} "
          f"({err_peak:+.2%}) of sigma_c = {sigma_c}")
    assert abs(err_peak) < 0.03
    wave = 2 * 1.0 * 100.0 * 0.1 / sigma_c     # 2 rho c v / sigma_c
    assert -wave - 0.01 < err_now <= 0.01


def test_momentum_is_conserved_through_conversions():
    """A free spinning, drifting disk (no walls reached, no gravity) whose rim converts and
    tears: sum m v stays at its initial value to 1e-12 of sum m |v|."""
    text = """
[simulation]
dim = 2
domain = { lower = [0.0, 0.0], upper = [4.0, 4.0] }
dx = 0.05
particles_per_cell = 2
transfer = "mls"
end_time = 0.06
[[materials]]
name = "disk"
type = "fixed_corotated"
density = 1.0
E = 1.0e3
nu = 0.3
failure = { model = "spb", grid_energy = 20.0, bond_energy = 0.05 }
[[bodies]]
material = "disk"
shape = "sphere"
center = [2.0, 2.0]
radius = 0.4
velocity = [0.5, -0.3]
angular_velocity = 20.0
"""
    sim = build(parse_scene(text, "<disk>"))
    p = sim.particles
    p0 = (p["mass"][:, None] * p["v"]).sum(axis=0)
    scale = (p["mass"] * np.linalg.norm(p["v"], axis=1)).sum()
    drift = []

    def observe(sim):
        q = sim.particles
        drift.append(np.abs((q["mass"][:, None] * q["v"]).sum(axis=0) - p0).max() / scale)

    run(sim, 0.06, observe)
    ext = sim.extensions[0]
    print(f"momentum drift {max(drift):.2e} over {len(drift)} steps; PD {ext.pd_global} of "
          f"{p.n}, half-bonds broken {ext.broken}, held {ext.held}")
    assert ext.pd_global > 0.1 * p.n and ext.broken > 0     # conversions and tearing
    assert ext.held == 0 and np.abs(p["x"] - 2.0).max() < 1.5   # no wall reached
    # Round-off only: about 1e-16 per step and operation.
    assert max(drift) < 1e-12


def test_separation_elongation_follows_the_horizon_not_the_grid():
    """003 §6.4.2 claims the stretched bar separates at an elongation the grid barely affects.
    Under eq. 6.11-6.12 a bond breaks at a strain ~ delta^-1/2, so that holds for a horizon
    fixed in length, not for one of 3.015 spacings that shrinks with dx. Measured
    (scripts/study_spb_bar.py, dx = 0.028 / 0.014 / 0.007): fixed delta = 0.0422 gives
    0.0304 / 0.0331 / 0.0313; delta = 3.015 spacings 0.030 / 0.062 / 0.081. Here the two
    coarser spacings: fixed delta within 15 % (the separation is detected at every fifth
    step, 2-5 % of the separation time, and the coarse bar is 3.5 cells wide: 9 % apart
    measured); 3.015 spacings at least 1.5x apart (sqrt 2 from delta^-1/2 alone; 2.0x
    measured)."""
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    from study_spb_bar import run as bar_run

    fixed = [bar_run(dx, 0.15, 3.015 * 0.014)["elongation"] for dx in (0.028, 0.014)]
    scaled = [bar_run(dx, 0.15)["elongation"] for dx in (0.028, 0.014)]
    print(f"elongation at separation, fixed delta: {fixed}, delta = 3.015 spacings: {scaled}")
    assert abs(fixed[1] / fixed[0] - 1.0) < 0.15
    assert scaled[1] / scaled[0] > 1.5
