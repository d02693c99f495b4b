"""Grid-node kernels. They take flattened views (``mass`` (N,), vectors (N, dim)), so one
kernel serves 2D and 3D blocks."""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def update_velocity(mass, momentum, impulse, split_force, gravity, dt, velocity,
                    velocity_old, keep_old):
    """Explicit symplectic-Euler grid update (000 eq. 3.1, §3.3).

    ``v_i = (p_i + dt f_i) / m_i + dt g`` on nodes with mass; ``velocity_old`` gets
    ``p_i / m_i`` when ``keep_old`` (FLIP). Nodes without mass get zero velocity."""
    dim = velocity.shape[1]
    for n in range(mass.shape[0]):
        m = mass[n]
        if m > 0.0:
            inv_m = 1.0 / m
            for a in range(dim):
                v_old = momentum[n, a] * inv_m
                v_new = v_old
                if split_force:
                    v_new += impulse[n, a] * inv_m
                velocity[n, a] = v_new + dt * gravity[a]
                if keep_old:
                    velocity_old[n, a] = v_old
        else:
            for a in range(dim):
                velocity[n, a] = 0.0
