"""The Kalthoff-Winkler crack angle (issue 10: 70 +- 6 degrees from the notch direction at
1 mm; experiment ~70, Silling 2003 ~68) through scripts/study_kalthoff_winkler.py: its angle
measurement on a drawn crack, and the angle of the 1 mm run with the notches cut as 2 mm gaps
(`--notch-width`). With zero-width pre-cracks (the shipped scene's notches) the 1 mm
ensemble mean is 59.5 degrees, below the band; which notch the issue means is open
(docs/studies.md, "The notch as a gap")."""

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))

from study_kalthoff_winkler import NOTCH, NOTCH_Y, crack_angles, plate, run  # noqa: E402


def test_angle_measurement_recovers_a_drawn_crack():
    """Damage 1 on the points within half a spacing of a line from each tip at 70 degrees
    (mirrored at the lower tip), 0 elsewhere: the measured start angles are 70 to within
    the lattice's staircase (0.5 degree)."""
    dx = 1e-3
    x0, _ = plate(dx)
    phi = np.zeros(len(x0))
    for sign in (1, -1):
        d = (x0 - np.array([NOTCH, sign * NOTCH_Y])) * np.array([1.0, sign])
        direction = np.array([np.cos(np.radians(70.0)), np.sin(np.radians(70.0))])
        along = d @ direction
        across = np.abs(d @ np.array([-direction[1], direction[0]]))
        phi[(along > 0) & (across <= 0.5 * dx)] = 1.0
    angles = [a for a, _ in crack_angles(x0, phi, dx)]
    assert np.allclose(angles, 70.0, atol=0.5), angles


def test_one_mm_angle_with_notch_gaps_is_in_the_band():
    """The issue's 1 mm run (PMB plane strain, delta = 3.015 dx, s0 from G0, 16 m/s on the
    impact set, 90 us) with 2 mm notch gaps, over 6 runs whose initial positions carry
    +-1e-4 dx noise (seeds 0-5): the mean of the per-run mean angles is inside 70 +- 6.
    Measured 63.1, 65.7, 64.8, 66.1, 65.9, 65.3 (mean 65.1, run s.d. 1.1, standard error
    0.45: 2.5 of them above the band's edge; the first 4 alone give 64.9, where one run
    alone can fall below the edge, 63.1). Before pre-crack ties were decided by the
    closed-segment rule (families._side): 65.0, 66.2, 65.0, 64.9 over seeds 0-3."""
    means = []
    for seed in range(6):
        body, _ = run(1e-3, perturb=1e-4, seed=seed, notch_width=2e-3)
        x0 = body.pts.x0[: body.pts.n_owned]
        means.append(np.mean([a for a, _ in crack_angles(x0, body.damage(), 1e-3)]))
    print(f"Kalthoff-Winkler, 1 mm, 2 mm notch gaps: run means {np.round(means, 1)}")
    assert 64.0 <= np.mean(means) <= 76.0
