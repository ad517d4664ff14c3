"""Building tools: the mesh stage, normals and Nagata patches from a mesh, outputs, convert, refinement."""
