"""The scripts that rebuild the paper's tables and figures, and this project's own results, from an
MLflow store of the runs they sweep."""
