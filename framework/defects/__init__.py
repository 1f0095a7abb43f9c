"""Defects of a print against its design: how well the caustic pins each height sample down
(information.py), the sparse deviation from the design the caustic asks for (design_fit.py),
the regions of that deviation measured and classified (regions.py), and the report (report.py).
docs/method.md, "Defects against the design"."""
