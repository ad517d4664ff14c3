"""gmsh-specific meshing: the session, planar loops in (u, v), the fill of empty faces, loop cuts, untangling."""
