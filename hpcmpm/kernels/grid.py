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
    g0, g1 = dt * gravity[0], dt * gravity[1]
    g2 = dt * gravity[2] if dim == 3 else 0.0
    for n in range(mass.shape[0]):
        m = mass[n]
        if m > 0.0:
            inv_m = 1.0 / m
            # Components written out (dim is 2 or 3): a loop over a run-time dim is not
            # unrolled, and this kernel touches every node of the block each step.
            u0 = momentum[n, 0] * inv_m
            u1 = momentum[n, 1] * inv_m
            u2 = momentum[n, 2] * inv_m if dim == 3 else 0.0
            if keep_old:
                velocity_old[n, 0] = u0
                velocity_old[n, 1] = u1
                if dim == 3:
                    velocity_old[n, 2] = u2
            if split_force:
                u0 += impulse[n, 0] * inv_m
                u1 += impulse[n, 1] * inv_m
                if dim == 3:
                    u2 += impulse[n, 2] * inv_m
            velocity[n, 0] = u0 + g0
            velocity[n, 1] = u1 + g1
            if dim == 3:
                velocity[n, 2] = u2 + g2
        else:
            velocity[n, 0] = 0.0
            velocity[n, 1] = 0.0
            if dim == 3:
                velocity[n, 2] = 0.0


# -- halo exchange of grid regions (`Domain._exchange_regions`) -------------------------------
@njit(cache=True)
def gather_nodes(field, index, buf, start):
    """buf[start + k c + a] = field[index[k], a]: the listed nodes of an (N, c) field, in list
    order, into a message buffer."""
    c = field.shape[1]
    for k in range(index.shape[0]):
        n = index[k]
        base = start + k * c
        for a in range(c):
            buf[base + a] = field[n, a]


@njit(cache=True)
def scatter_nodes(field, index, buf, start, add):
    """The inverse of `gather_nodes`: field[index[k], a] += (or, without ``add``, =) the
    buffer's values, in list order (a node listed twice gets its sums in that order)."""
    c = field.shape[1]
    for k in range(index.shape[0]):
        n = index[k]
        base = start + k * c
        if add:
            for a in range(c):
                field[n, a] += buf[base + a]
        else:
            for a in range(c):
                field[n, a] = buf[base + a]
