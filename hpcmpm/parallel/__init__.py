"""MPI: decomposition, halo exchanges, migration, load balance and reductions.

The only package that imports mpi4py; everything else talks to `Domain` verbs.
"""

from .comm import Communicator
from .domain import Domain, make_domain
from .launch import check_launch

__all__ = ["Communicator", "Domain", "check_launch", "make_domain"]
