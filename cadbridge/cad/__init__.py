"""The CAD model and what needs a whole model: faces and trims, trim decisions, box tree, search index."""
