"""Meshes: the Mesh value, validation, topology, quality, shapes and file I/O."""

from willmore_nlp.mesh.core import Mesh, MeshError

__all__ = ["Mesh", "MeshError"]
