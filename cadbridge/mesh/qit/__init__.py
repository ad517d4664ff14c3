"""The quasi-isotropic triangulation of Herrero Adan 2020: the mesher and its strip relaxation."""
