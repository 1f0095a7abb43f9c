"""Blur-free forward rendering of the caustic by wavefront triangles (docs/method.md, "The forward model")."""
