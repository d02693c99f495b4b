"""Model-independent bond kernels (hpcmpm/pd/geometry.py, the time step of moduli.py) and
the serial integrator's body force (integrator.py), on hand-made bond lists."""

import numpy as np

from hpcmpm.pd.geometry import break_stretched


def test_break_stretched_breaks_bonds_whose_partner_left_the_halo():
    """An intact half-bond whose partner is not in the owned + halo rows (slot -1: beyond
    the halo reach, which assumes every bond longer than (delta + h/2)(1 + s_reach) broke)
    breaks and is counted; a bond exactly at s0 stays (s > s0 breaks), one just above
    breaks, a broken one is not counted again."""
    x0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    s0 = 0.25
    x = x0.copy()
    x[1, 0] = 1.0 + s0                       # bond 0-1 at s = s0 exactly (1.25 - 1) / 1
    x[2, 1] = 1.0 + s0 + 1e-9                # bond 0-2 just above
    offsets = np.array([0, 4, 4, 4, 4])
    slot = np.array([1, 2, -1, -1], np.int32)
    status = np.array([1, 1, 1, 0], np.int8)
    broken = break_stretched(x, x0, offsets, slot, status, s0, 1)
    assert status.tolist() == [1, 0, 0, 0]
    assert broken == 2


def test_silling_askari_step_sums_intact_bonds_only():
    """dt_p = sqrt(2 rho_p / sum_q V_q c w_pq / |X|) over the intact bonds (moduli.py): a
    broken bond no longer stiffens its particle; a particle without intact bonds has no
    limit (inf)."""
    from hpcmpm.pd.moduli import silling_askari_steps

    x0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 3.0]])
    vol = np.array([1.0, 2.0, 0.5])
    rho = np.array([2.0, 3.0, 4.0])
    c = 5.0
    offsets = np.array([0, 2, 3, 4])
    slot = np.array([1, 2, 0, 0], np.int32)
    weight = np.array([0.7, 0.9, 0.7, 0.9])
    status = np.array([1, 0, 1, 0], np.int8)
    out = np.empty(3)
    best = silling_askari_steps(x0, vol, rho, offsets, slot, status, weight, c, 3, out)
    want = [np.sqrt(2 * 2.0 / (2.0 * c * 0.7 / 1.0)), np.sqrt(2 * 3.0 / (1.0 * c * 0.7 / 1.0)),
            np.inf]
    # rel 1e-15: the same few operations (measured equal to the last bit).
    np.testing.assert_allclose(out, want, rtol=1e-15)
    assert best == min(want)


def test_serial_body_force_is_per_volume():
    """`PDBody.step`: v += dt (f + b V) / m with b a force per volume: particles without
    bonds (m = rho V) accelerate at b / rho whatever their volume."""
    from hpcmpm.pd.families import find_families
    from hpcmpm.pd.integrator import PDBody
    from hpcmpm.pd.pmb import PMB

    x0 = np.array([[0.0, 0.0], [10.0, 0.0]])            # far apart: no bonds
    ids = np.arange(2, dtype=np.int64)
    fam = find_families(x0, ids, 2, 1.0, 3.015)
    assert fam.bonds.n_bonds == 0
    body = PDBody(x0, np.array([0.5, 2.0]), ids, 4.0, fam, PMB(1.0, 0.1),
                  body_force=np.array([8.0, -2.0]))
    body.step(0.1)
    assert np.array_equal(body.v, [[0.2, -0.05], [0.2, -0.05]])
