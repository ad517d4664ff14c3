"""Code shared by the tests and the benchmarks (no tests here).

* `nagata_shapes`: structured meshes of the analytic test geometries, with exact normals.
* `qit_examples`: the NURBS test surfaces of Herrero Adan & Cardoso (2020), appendix D.
* `iges_fixtures`: hand-made IGES text.
* `toolfile_reference`: an independent reader of the tool file (docs/toolfile.md).
* `occ`: OpenCASCADE as the reference (read a file, faces and edges, distances, areas, normals,
  the nearest point on a B-spline surface).
* `surfaces`: NURBS surfaces with known geometry (circle arcs, cylinders, spheres, tori) and
  random patches.
* `scans`: a synthetic scan of the U-shape die.
"""
