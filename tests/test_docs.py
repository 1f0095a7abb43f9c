"""The manual says what the code holds: the keys page is made from conf/, and the reference names
every module of the plugin contracts, the operators, the regularisers and the solvers."""

from __future__ import annotations

import re
from pathlib import Path

from experiments.apps.config_reference import Key, config_keys, main

ROOT = Path(__file__).resolve().parents[1]
# Where the public classes and functions of the contracts, operators, regularisers and solvers live
# (operators/ with its subpackages).
DOCUMENTED = ("framework/core/contracts", "regularizers", "framework/reconstruction/solvers",
              "framework/reconstruction/starts", "framework/optimization", "operators/**")


def test_the_keys_page_is_made_from_the_configs():
    assert main(["--check", "--out", str(ROOT / "docs" / "guide" / "keys.md")]) == 0


def test_keys_are_read_with_their_sections_defaults_and_continued_comments():
    text = """# a header
defaults:
  - scene: print_lines
photons: 1048576           # photons per render
                           # at most
solver:
  max_iter: 200            # the cap
  step_size:
    tau: 0.1
hydra:
  run:
    dir: outputs           # Hydra's own
seed: 0
"""
    assert config_keys(text) == [Key("photons", "1048576", "photons per render at most"),
                                 Key("solver.max_iter", "200", "the cap"), Key("solver.step_size.tau", "0.1", ""),
                                 Key("seed", "0", "")]


def test_the_reference_names_every_module_of_the_contracts_operators_regularisers_and_solvers():
    named = {m for page in (ROOT / "docs" / "reference").glob("*.md")
             for m in re.findall(r"^::: ([\w.]+)$", page.read_text(), flags=re.M)}
    modules = {path.relative_to(ROOT).with_suffix("").as_posix().replace("/", ".")
               for folder in DOCUMENTED for path in ROOT.glob(f"{folder}/*.py")
               if not path.name.startswith("_")}
    assert modules - named == set()
