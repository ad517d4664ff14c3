"""NURBS surfaces fitted to points (scans, FE nodes, Nagata samples), with their base surfaces."""
