"""Real CAD repaired or analysed before meshing: creases, folds, loop excursions, trim knots, the mesher's copy."""
