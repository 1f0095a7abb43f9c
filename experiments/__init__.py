"""The project's commands (experiments/apps/), the scripts that rebuild the paper's tables and
figures (experiments/paper/) and the benchmarks (experiments/benchmarks/); their old flat names
still import for one release (experiments/moved.py)."""

from experiments.moved import install

install()
