"""Code shared by the tests and the benchmarks (no tests here).

* `nagata_shapes`: structured meshes of the analytic test geometries, with exact normals.
* `qit_examples`: the NURBS test surfaces of Herrero Adan & Cardoso (2020), appendix D.
* `iges_fixtures`: hand-made IGES text.
* `toolfile_reference`: an independent reader of the tool file (docs/toolfile.md).
"""
