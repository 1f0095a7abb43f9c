import pytest
import torch

from framework.core.callbacks import Callback, Checkpointer, MetricsHistory
from framework.core.checkpoint import load_checkpoint, restore, resume, save_checkpoint
from framework.reconstruction.solvers import BacktrackingStep, GradientDescent, PixelLandweber, WaveletLandweber
from tests.framework.toy import DTYPE, L1, Bounds, OrthogonalTransform, WaveletL1, make_problem


class InterruptAt(Callback):
    def __init__(self, k):
        self.k = k

    def on_iteration(self, solver, record):
        if record.iteration == self.k:
            raise KeyboardInterrupt


def _m2(op_noise=0.0):
    data, op, A, b, d_true, L = make_problem(op_noise=op_noise)
    return PixelLandweber(data, torch.zeros(8, 8, dtype=DTYPE), BacktrackingStep(20.0 / L, grow=1.5),
                          regularizers=[L1(2e-3), Bounds()])


@pytest.mark.parametrize("op_noise", [0.0, 1e-3])  # deterministic, and drawing from the global RNG
def test_interrupted_then_resumed_run_equals_uninterrupted_bit_for_bit(tmp_path, op_noise):
    torch.manual_seed(123)
    full = _m2(op_noise).run(12)

    torch.manual_seed(123)
    path = tmp_path / "ckpt.pt"
    first = _m2(op_noise)
    with pytest.raises(KeyboardInterrupt):
        first.run(12, [Checkpointer(path, every=5), InterruptAt(7)])
    torch.manual_seed(999)  # the RNG moves on in between; the checkpoint restores it
    torch.randn(10)
    fresh = _m2(op_noise)
    hist = MetricsHistory()
    resumed = resume(fresh, path, 12, [hist])

    assert torch.equal(resumed.d, full.d)
    assert resumed.iterations == 12 and len(resumed.history) == 12
    assert [r.objective for r in resumed.history] == [r.objective for r in full.history]
    assert [r.step_size for r in resumed.history] == [r.step_size for r in full.history]
    assert fresh.step_size.tau == _tau_after(full)
    assert len(hist.records) == 12
    assert resumed.elapsed_s >= resumed.history[4].elapsed_s
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]  # no temporary files left behind


def _tau_after(full_result):
    return min(full_result.history[-1].step_size * 1.5, float("inf"))


def test_m3_checkpoint_restores_wavelet_coefficients(tmp_path):
    data, *_, L = make_problem()

    def build():
        W = OrthogonalTransform(8, [])
        return WaveletLandweber(data, torch.zeros(8, 8, dtype=DTYPE), 0.5 / L, wavelet=W,
                                wavelet_regularizer=WaveletL1(W, 1e-3, []), pixel_regularizers=[Bounds()])

    full = build().run(6)
    a = build()
    a.run(3)
    save_checkpoint(a, tmp_path / "m3.pt")
    b = restore(build(), tmp_path / "m3.pt")
    assert torch.equal(b.coefficients, a.coefficients) and b.iteration == 3
    assert torch.equal(b.run(6).d, full.d)


def test_checkpoint_errors_are_clear(tmp_path):
    data, *_, L = make_problem()
    gd = GradientDescent(data, torch.zeros(8, 8, dtype=DTYPE), 1.0 / L)
    gd.run(2)
    save_checkpoint(gd, tmp_path / "gd.pt")
    with pytest.raises(ValueError, match="gradient_descent|GradientDescent"):
        restore(_m2(), tmp_path / "gd.pt")
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="format"):
        load_checkpoint(tmp_path / "other.pt")
    small = GradientDescent(data, torch.zeros(4, 4, dtype=DTYPE), 1.0 / L)
    with pytest.raises(ValueError, match="shape"):
        restore(small, tmp_path / "gd.pt")


def test_a_parametric_fit_of_tracks_resumes_bit_for_bit(tmp_path):
    import numpy as np

    from framework.reconstruction.solvers.parametric_fit import ParametricFit
    from framework.tracks.track_heights import TrackHeights, TrackSettings
    from framework.tracks.track_set import Track, TrackSet

    m = 16
    data, *_ = make_problem(m=m, n=18)
    tracks = TrackSet((Track("line", np.array([[-15.0, 3.0], [15.0, 3.0]]), np.full(7, 2.0), np.full(7, 4.0),
                             np.zeros(7)),))

    def build():
        rep = TrackHeights(tracks, m, 1.0, 25.0, TrackSettings(knot_mm=5.0, residual_mm=10.0), DTYPE)
        return ParametricFit(data, rep, memory=4)

    full = build().run(8)
    path = tmp_path / "tracks.pt"
    first = build()
    with pytest.raises(KeyboardInterrupt):
        first.run(8, [Checkpointer(path, every=3), InterruptAt(4)])
    resumed = resume(build(), path, 8, [])
    assert torch.equal(resumed.d, full.d)
    assert [r.objective for r in resumed.history] == [r.objective for r in full.history]
    assert full.history[-1].objective < full.history[0].objective
