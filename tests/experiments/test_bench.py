"""sfc-bench runs end to end on a tiny budget and reports every figure it promises."""

from __future__ import annotations

import json

import pytest
import torch

from experiments.bench import main


def test_bench_prints_the_promised_figures(capsys):
    main(["--photons", "200000", "--grad-photons", "30000", "--splat-photons", "3000", "--chunk-size", "8192",
          "--reference-photons", "20000"])
    report = json.loads(capsys.readouterr().out)
    assert report["forward_photons_per_s"] > 0 and report["forward_backward_photons_per_s"] > 0
    assert 0.0 < report["forward_split"]["trace_fraction"] < 1.0
    reference = report["torch_reference_path"]
    assert reference["forward_photons_per_s"] > 0 and reference["forward_backward_photons_per_s"] > 0
    comparison = report["splat_comparison"]
    assert comparison["relative_image_difference"] < 1e-5 and comparison["speedup"] > 0
    assert report["gradient_paper_photons"]["photons"] == 30000


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without a GPU")
def test_bench_on_cuda_without_a_gpu_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["--device", "cuda"])
    assert "needs a CUDA GPU" in capsys.readouterr().err
