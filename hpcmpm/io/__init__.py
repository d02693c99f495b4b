"""Output: HDF5 frames + XDMF for ParaView, checkpoints, and ``hpcmpm info`` (docs/output.md).

Only `Communicator` verbs reach MPI from here; ``domain.comm`` is passed unopened to h5py's
``mpio`` driver when h5py has parallel HDF5.
"""

from .checkpoint import latest_checkpoint, read_checkpoint, write_checkpoint
from .frames import FrameWriter, read_frame

__all__ = ["FrameWriter", "read_frame", "write_checkpoint", "read_checkpoint",
           "latest_checkpoint"]
