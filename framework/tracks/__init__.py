"""A print as tracks: beads along its tool path (or its design's skeleton) with profiles along
each path, drops and a residual grid (docs/method.md, "Tracks"); the representation plugin
``tracks``, its global search and the defects read from a fit."""
