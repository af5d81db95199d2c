"""Triangle meshes: I/O, topology checks, subdivision, simplification, re-meshing, initialisation."""
