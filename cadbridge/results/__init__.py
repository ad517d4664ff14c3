"""Nodal simulation results on the exact CAD (Hawkins 1989): mapping, contour lines, bands,
their export. See docs/results.md."""

from cadbridge.results.bands import BandRegion, Bands, band_areas
from cadbridge.results.contours import ContourLines, Contours, contour, contour_lines, make_levels
from cadbridge.results.fields import FieldError, NodalField, read_results
from cadbridge.results.mapping import ResultMapping, map_results

__all__ = ["BandRegion", "Bands", "ContourLines", "Contours", "FieldError", "NodalField", "ResultMapping",
           "band_areas", "contour", "contour_lines", "make_levels", "map_results", "read_results"]
