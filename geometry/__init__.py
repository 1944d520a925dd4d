"""Mesh algorithms in numpy: normals and receivers, crack-free refinement, tetrahedra."""
