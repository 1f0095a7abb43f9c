"""Defects of a print against its design (docs/method.md, "Defects against the design"): how well
the caustic pins each height sample down (information.py), where the result leaves the design
(regions.py), the defect models of a design (models.py) fitted to the photo to size and name each
defect (fit.py), and the report's files and sentences (report.py)."""
