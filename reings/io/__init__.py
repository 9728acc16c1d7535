"""File formats: the standard 3DGS .ply (`ply`)."""
from .ply import PlyError, read_ply, write_ply

__all__ = ["PlyError", "read_ply", "write_ply"]
