"""hpcmpm: MPI-distributed Material Point Method with peridynamics."""

__version__ = "0.1.0"
