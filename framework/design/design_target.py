"""The target image of a caustic design: read from a file or generated, checked, on the receiver.

A target is what the designed glass should cast on the screen: relative brightness on a square
image, rows along +y (the first row of a PNG/JPG/TIFF is the top, as in a photo, and is flipped;
an .npy is taken as written by ``sfc-simulate``, row 0 at -y). Colour images are reduced to one
channel (``channel``: luminance, r, g or b). Built-in targets, for tests and comparisons:

- ``grace_hopper``: matplotlib's sample photo grace_hopper.jpg, centre-cropped to a square;
- ``logo``: matplotlib's logo2.png, its opaque parts bright on black, padded to a square;
- ``ring``: a bright annulus (radius 0.55, width 0.12 of the half side) on black;
- ``text``: the configured text in bold white letters on black.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from framework.files.height_field_io import load_npy
from framework.files.image_io import existing_file
from operators.optics.inverse_refraction import deflection_angle, flat_magnification
from operators.scene import Scene
from operators.values import checked_whole

__all__ = ["BUILT_IN_TARGETS", "CHANNELS", "DesignTarget", "built_in_target", "load_target", "paraxial_shadow",
           "screen_reach"]

BUILT_IN_TARGETS = ("grace_hopper", "logo", "ring", "text")
CHANNELS = ("luminance", "r", "g", "b")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
LUMINANCE = (0.2126, 0.7152, 0.0722)  # Rec. 709 weights of linear r, g, b


@dataclass(frozen=True)
class DesignTarget:
    """A checked target: ``image`` (n, n) float64 >= 0 with some light, rows along +y; ``source``
    the file or built-in it came from; ``absolute``: an .npy of irradiance (W per scene unit^2),
    whose total power the design compares with what reaches the screen."""

    image: np.ndarray
    source: str
    absolute: bool


def _square_resized(array: np.ndarray, resolution: int) -> np.ndarray:
    """A grey image (H, W) in [0, 1], first row on top, centre-cropped to a square, resampled to
    (resolution, resolution) by Lanczos and flipped to rows along +y."""
    h, w = array.shape
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    square = np.ascontiguousarray(array[top:top + side, left:left + side], dtype=np.float32)
    resized = np.asarray(Image.fromarray(square, mode="F").resize((resolution, resolution), Image.LANCZOS))
    return np.clip(resized.astype(np.float64), 0.0, None)[::-1].copy()


def _sample_data(name: str) -> Image.Image:
    import matplotlib.cbook as cbook

    with cbook.get_sample_data(name) as stream:
        return Image.open(stream).copy()


def _text_image(text: str, resolution: int) -> np.ndarray:
    """``text`` in bold white on black (H, W) in [0, 1], first row on top, rendered by matplotlib."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(4, 4), dpi=max(resolution // 4, 16), facecolor="black")
    figure.text(0.5, 0.5, text, color="white", ha="center", va="center", fontsize=200 / max(len(text), 1) ** 0.5,
                fontweight="bold", family="DejaVu Sans")
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba(), dtype=np.float64) / 255.0
    return rgba[..., :3] @ np.asarray(LUMINANCE)


def built_in_target(name: str, resolution: int, text: str = "SfC") -> np.ndarray:
    """The built-in target ``name`` (:data:`BUILT_IN_TARGETS`) as (resolution, resolution), rows +y."""
    if name == "grace_hopper":
        grey = (
            np.asarray(_sample_data("grace_hopper.jpg").convert("RGB"), dtype=np.float64)
            / 255.0
            @ np.asarray(LUMINANCE)
        )
        return _square_resized(grey, resolution)
    if name == "logo":
        rgba = np.asarray(_sample_data("logo2.png").convert("RGBA"), dtype=np.float64) / 255.0
        grey = rgba[..., 3] * (0.25 + 0.75 * (rgba[..., :3] @ np.asarray(LUMINANCE)))
        h, w = grey.shape
        side = max(h, w)
        padded = np.zeros((side, side))
        padded[(side - h) // 2:(side - h) // 2 + h, (side - w) // 2:(side - w) // 2 + w] = grey
        return _square_resized(padded, resolution)
    if name == "ring":
        fine = 4 * resolution  # area-averaged from a 4 x finer grid: smooth edges
        centres = (np.arange(fine) + 0.5) / fine * 2.0 - 1.0
        radius = np.hypot(*np.meshgrid(centres, centres))
        ring = (np.abs(radius - 0.55) <= 0.06).astype(np.float64)
        return ring.reshape(resolution, 4, resolution, 4).mean(axis=(1, 3))
    if name == "text":
        if not isinstance(text, str) or not text.strip():
            raise ValueError(f"target.text={text!r} must be some text to draw, e.g. SfC")
        return _square_resized(_text_image(text, resolution), resolution)
    raise ValueError(f"target.image={name!r} is neither a file nor a built-in target; use a .png/.jpg/.tif/.npy "
                     f"path or one of {', '.join(BUILT_IN_TARGETS)}")


def _file_image(path: Path, channel: str, resolution: int) -> tuple[np.ndarray, bool]:
    suffix = path.suffix.lower()
    if suffix == ".npy":
        array = load_npy(path, "write it again with numpy.save")
        if array.ndim == 3 and array.shape[0] == 1:
            array = array[0]
        if array.ndim != 2 or array.shape[0] != array.shape[1]:
            raise ValueError(f"target {path.name} has shape {array.shape}; an .npy target is one square (n, n) "
                             "image (or (1, n, n) as sfc-simulate writes it)")
        if not np.isfinite(array).all():
            raise ValueError(f"target {path.name} contains NaN or infinite values; clean it first")
        if array.shape[0] != resolution:
            raise ValueError(f"target {path.name} is {array.shape[0]} x {array.shape[0]} but the screen has "
                             f"{resolution} x {resolution} pixels; set target.resolution={array.shape[0]}")
        return np.asarray(array, dtype=np.float64), True
    if suffix not in IMAGE_SUFFIXES:
        raise ValueError(f"unsupported target file type {suffix!r} for {path.name}; use .png, .jpg, .tif or .npy")
    try:
        with Image.open(path) as img:
            array = np.asarray(img)
    except (UnidentifiedImageError, OSError) as error:
        raise ValueError(
            f"{path} cannot be read as an image ({str(error)[:80]}); save it again as PNG/JPG/TIFF"
        ) from None
    scale = float(np.iinfo(array.dtype).max) if np.issubdtype(array.dtype, np.integer) else 1.0
    array = array.astype(np.float64) / scale
    if array.ndim == 3:
        rgb = array[..., :3] if array.shape[-1] >= 3 else np.repeat(array[..., :1], 3, axis=-1)
        array = rgb @ np.asarray(LUMINANCE) if channel == "luminance" else rgb[..., "rgb".index(channel)]
    if not np.isfinite(array).all():
        raise ValueError(f"target {path.name} contains NaN or infinite values; clean it first")
    return _square_resized(array, resolution), False


def load_target(image: str, resolution: int, base_dir: str | Path | None = None, channel: str = "luminance",
                text: str = "SfC") -> DesignTarget:
    """The target ``image`` (a built-in name or a file path, relative to ``base_dir``) on a screen
    of (resolution, resolution) pixels, checked: a missing file, an unreadable or non-square .npy,
    negative, non-finite or all-black values each raise a one-line error naming the fix."""
    resolution = checked_whole(resolution, "target.resolution", 8,
                               must="must be an integer >= 8 (screen pixels per side)", example="256")
    if channel not in CHANNELS:
        raise ValueError(f"target.channel={channel!r} must be one of {', '.join(CHANNELS)}")
    if not isinstance(image, str) or not image:
        raise ValueError(f"target.image={image!r} must be a file (.png/.jpg/.tif/.npy) or one of "
                         f"{', '.join(BUILT_IN_TARGETS)}")
    if image in BUILT_IN_TARGETS:
        array, absolute, source = built_in_target(image, resolution, text), False, f"built-in:{image}"
    else:
        path = Path(image).expanduser()
        if base_dir is not None and not path.is_absolute():
            path = Path(base_dir) / path
        if path.suffix.lower() not in (".npy", *IMAGE_SUFFIXES) and not path.exists():
            raise ValueError(f"target.image={image!r} is neither a file nor a built-in target; use a "
                             f".png/.jpg/.tif/.npy path or one of {', '.join(BUILT_IN_TARGETS)}")
        path = existing_file(path, "target image")
        array, absolute = _file_image(path, channel, resolution)
        source = str(path)
    if array.min() < 0.0:
        raise ValueError(f"target {source} has negative values (min {array.min():.3g}); a caustic is light >= 0")
    if array.max() <= 0.0:
        raise ValueError(f"target {source} is all black; a design needs some light in the target")
    return DesignTarget(array, source, absolute)


def paraxial_shadow(scene: Scene) -> float:
    """Half width of flat glass's shadow on ``scene``'s receiver with no optical elements (scene units)."""
    return scene.substrate.half_width * flat_magnification(scene.light.position[2], scene.substrate.thickness,
                                                           float(max(scene.indices)), scene.receiver.z)


def screen_reach(scene: Scene, max_slope: float) -> float:
    """Half width of the square the glass can light on the screen (scene units): flat glass's
    shadow plus the largest deflection a surface of slope ``max_slope`` gives, over the distance
    from the top to the screen."""
    distance = scene.substrate.thickness - scene.receiver.z
    deflection = deflection_angle(math.atan(max_slope), float(max(scene.indices)))
    return paraxial_shadow(scene) + distance * math.tan(deflection)
