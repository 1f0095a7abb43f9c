"""From a camera photo of the caustic on the screen to a receiver-aligned irradiance image.

The chain (docs/photo_import.md): read the photo (values as a fraction of full scale, row 0 =
top; a camera RAW file linearly, its black and white levels from the file:
framework/lab/raw_photo.py) -> mark saturated pixels on the raw values -> subtract the black level -> invert the camera
response -> pick the channel -> subtract a dark frame -> divide by a flat field -> homography
from the receiver's four corners in the photo -> average supersample^2 bilinear samples per
receiver pixel. The result follows framework/files/image_io.py: (c, n, n) with [row, col] = [y, x],
row 0 at y = -W, pixel centres at -W + (p + 0.5) 2W / n.

The geometry (corners, homography, resampling) is framework/lab/photo_geometry.py; synthetic photos
for tests are framework/lab/photo_synthesis.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image, UnidentifiedImageError

from framework.files.height_field_io import load_npy
from framework.files.image_io import existing_file
from framework.lab.lens import LensModel
from framework.lab.raw_photo import RAW_SUFFIXES, read_raw
from framework.lab.screen_markers import MarkerSheet, detect_receiver
from framework.lab.photo_geometry import (check_corners, check_receiver_grid, homography, inside_receiver, rectify,
                                          saturated_receiver_pixels)
from operators.values import checked_number, checked_whole

__all__ = ["FULL_SCALE", "PhotoImport", "read_photo", "linearize", "import_photo"]

Response = Literal["linear", "srgb", "gamma"]
Channel = Literal["grey", "red", "green", "blue"]

FULL_SCALE = {8: 255, 16: 65535}
RAW_DEPTH = -1  # the "bit depth" of a camera RAW file, read as fractions of its own full scale
FLAT_FLOOR = 1e-3  # flat pixels below this fraction of the flat's mean are unusable
_SAVE_AS = ("give the camera's RAW file (.dng, .cr2, .nef, .arw, ...), save it as an 8- or 16-bit greyscale or RGB "
            "PNG/TIFF, or as a .npy float array of linear values")


# --- reading -------------------------------------------------------------------------------------

def _rawmode(img: Image.Image) -> str:
    """The decoder's raw mode of the first tile ('RGB;16B' for a 16-bit RGB PNG), '' if unknown."""
    try:
        args = img.tile[0][3]
    except (IndexError, TypeError, AttributeError):
        return ""
    return args if isinstance(args, str) else str(args[0]) if args else ""


def _pillow_bit_depth(img: Image.Image, name: str, what: str = "photo") -> int:
    """8 or 16 for a greyscale or RGB image Pillow decodes losslessly; ValueError otherwise."""
    mode, raw = img.mode, _rawmode(img)
    bits = getattr(img, "tag_v2", {}).get(258) if hasattr(img, "tag_v2") else None
    bits = tuple(bits) if isinstance(bits, (tuple, list)) else (bits,) if bits else ()
    if mode in ("L", "RGB") and (16 in bits or ";16" in raw):  # Pillow decodes these to 8 bits
        raise ValueError(f"{what} {name} is a 16-bit {'RGB' if mode == 'RGB' else 'greyscale'} image (mode "
                         f"{mode!r}, raw {raw!r}), which Pillow would truncate to 8 bits; save the channel you use "
                         "(e.g. green) as a 16-bit greyscale PNG/TIFF, or the image as a .npy float array of "
                         "linear values")
    if mode == "L" and raw in ("L;1", "L;2", "L;4", "L;2I", "L;4I", "L;1I"):
        raise ValueError(f"{what} {name} is a {raw[2]}-bit greyscale image (mode 'L', raw {raw!r}); {_SAVE_AS}")
    if mode in ("L", "RGB"):
        return 8
    if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
        return 16
    if mode == "I" and (bits == (16,) or ";16" in raw or img.format == "PNG"):
        return 16  # some Pillow versions open 16-bit grey PNGs as mode 'I'
    kind = {"1": "a 1-bit (black and white) image", "P": "a palette image", "F": "a 32-bit float image",
            "I": "a 32-bit integer image", "RGBA": "an RGB image with an alpha channel",
            "LA": "a greyscale image with an alpha channel"}.get(mode, "an image")
    fix = "drop the alpha channel" if mode in ("RGBA", "LA") else _SAVE_AS
    raise ValueError(f"{what} {name} is {kind} (mode {mode!r}); {fix}")


def _kind(depth: int) -> str:
    """What a frame of bit depth ``depth`` is, for messages."""
    return {0: "a linear float array", RAW_DEPTH: "a camera RAW file"}.get(depth, f"{depth}-bit")


def read_photo(path: str | Path, bit_depth: int | None = None) -> tuple[np.ndarray, int]:
    """The photo as float64 (H, W) or (H, W, 3) in [0, 1] (value / full scale), row 0 = top,
    and its bit depth (8, 16; 0 = a .npy float array of linear values; RAW_DEPTH = a camera RAW
    file, black level off, framework/lab/raw_photo.py).

    ``bit_depth`` (8, 16 or None = either) is what the photo must have; a mismatch is refused.
    """
    array, depth, _ = _checked_frame(path, bit_depth)
    return array, depth


def _checked_frame(path: str | Path, bit_depth: int | None) -> tuple[np.ndarray, int, str]:
    """:func:`read_photo` with the line saying what was read."""
    if bit_depth is not None:
        must = "must be 8, 16 or null (accept either)"
        bit_depth = checked_whole(bit_depth, "data.bit_depth", must=must)
        if bit_depth not in FULL_SCALE:
            raise ValueError(f"data.bit_depth={bit_depth!r} {must}")
    array, depth, read = _read_frame(path, "photo")
    if bit_depth is not None and depth != bit_depth:
        raise ValueError(f"photo {Path(path).name} is {_kind(depth)} but data.bit_depth={bit_depth}; set "
                         f"data.bit_depth={depth if depth > 0 else 'null'} or give the photo the camera actually wrote")
    return array, depth, read


def _read_frame(path: str | Path, what: str) -> tuple[np.ndarray, int, str]:
    """:func:`read_photo` without the bit-depth requirement, and a line saying what was read;
    ``what`` names the file in messages."""
    p = existing_file(path, what)
    suffix = p.suffix.lower()
    if suffix in RAW_SUFFIXES:
        frame = read_raw(p, what)
        return frame.values, RAW_DEPTH, frame.describe()
    if suffix == ".npy":
        array = load_npy(p, _SAVE_AS)
        if array.dtype.kind != "f":
            raise ValueError(f"{what} {p.name} holds {array.dtype} values; a .npy photo must be a float array of "
                             "linear values as a fraction of full scale (divide the counts by the white level)")
        depth = 0
    elif suffix in (".png", ".tif", ".tiff"):
        try:
            with Image.open(p) as img:
                depth = _pillow_bit_depth(img, p.name, what)
                array = np.asarray(img)
        except (UnidentifiedImageError, OSError) as error:
            raise ValueError(f"{what} {p.name} cannot be read as an image ({error}); {_SAVE_AS}") from None
        array = array.astype(np.float64) / FULL_SCALE[depth]
    else:
        raise ValueError(f"{what} {p.name} has the unsupported suffix {p.suffix!r}; {_SAVE_AS}")
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3)):
        raise ValueError(f"{what} {p.name} has shape {array.shape}; expected (H, W) or (H, W, 3)")
    array = array.astype(np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f"{what} {p.name} contains NaN or infinite values; clean it first")
    if array.min() < 0.0 or array.max() > 1.0:
        raise ValueError(f"{what} {p.name} holds values in [{array.min():.4g}, {array.max():.4g}]; .npy photos are "
                         "linear values as a fraction of full scale in [0, 1]: divide by the white level")
    height, width = array.shape[:2]
    return array, depth, f"{width} x {height} px, " + ("linear float .npy" if depth == 0 else f"{depth}-bit") + (
        " RGB" if array.ndim == 3 else " grey")


def linearize(values: np.ndarray, response: Response = "linear", gamma: float = 2.2) -> np.ndarray:
    """Linear values from encoded ones (same shape, fraction of full scale): the inverse camera
    response, ``linear`` (identity), ``srgb`` (inverse sRGB transfer) or ``gamma`` (v ** gamma).

    Negative inputs (noise below a subtracted black level) map to minus the response of |v|.
    """
    values = np.asarray(values, dtype=np.float64)
    if response == "linear":
        return values
    if response == "gamma":
        gamma = checked_number(gamma, "data.gamma", above=0.0, must="must be a positive exponent",
                               example="2.2 (linear = v ** gamma)")
        return np.sign(values) * np.abs(values) ** gamma
    if response == "srgb":
        v = np.abs(values)
        return np.sign(values) * np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    raise ValueError(f"data.response={response!r} must be 'linear', 'srgb' or 'gamma'")


# --- the import chain ----------------------------------------------------------------------------

@dataclass
class PhotoImport:
    """A photo turned into receiver data.

    image: (1, n, n) float64 linear irradiance, arbitrary scale, rows y-up; weights: (1, n, n)
    float64 in {0, 1} (0: the pixel saw saturated or unusable photo pixels); steps: what was done,
    in order; photo: (H, W) float64 the processed linear photo (row 0 = top); corners: (4, 2)
    [col, row]; homography: (3, 3) receiver (x, y) -> photo (col, row); bad_photo_pixels: (H, W)
    bool saturated or unusable photo pixels; half_width: receiver half width (scene units);
    left_out: receiver pixels at weight 0 by reason: ``unlit`` (outside the flat field's lit
    region), ``saturated`` (touching saturated photo pixels, inside the lit region).
    """

    image: np.ndarray
    weights: np.ndarray
    steps: list[str]
    photo: np.ndarray
    corners: np.ndarray
    homography: np.ndarray
    bad_photo_pixels: np.ndarray
    half_width: float
    path: Path = field(default_factory=Path)
    left_out: dict[str, int] = field(default_factory=dict)


def _select(values: np.ndarray, channel: Channel) -> np.ndarray:
    """(H, W, k) of the channels ``channel`` uses (k = 1 for grey photos)."""
    if values.ndim == 2:
        return values[..., None]
    return values if channel == "grey" else values[..., ["red", "green", "blue"].index(channel)][..., None]


def _linear_frame(raw: np.ndarray, depth: int, channel: Channel, black: float, response: Response,
                  gamma: float) -> np.ndarray:
    """(H, W) linear values of one frame: black level (DN) off, inverse response, channel (mean)."""
    encoded = _select(raw, channel) - black / FULL_SCALE.get(depth, 1)
    return linearize(encoded, response, gamma).mean(axis=-1)


def _undistorted(raw: np.ndarray, lens: LensModel | None, channel: Channel, saturation: float,
                 name: str) -> tuple[np.ndarray, np.ndarray]:
    """The photo (H, W[, 3]) as the ideal lens would see it (``lens`` None: as it is), and where it
    had saturated pixels before (bool (H, W), spread by the resampling's support)."""
    if lens is None:
        return raw, np.zeros(raw.shape[:2], dtype=bool)
    flags = (_select(raw, channel) >= saturation).any(axis=-1).astype(np.float64)
    return lens.undistort(raw, name), lens.undistort(flags, name) > 0.0


def _read_like(path: str | Path, what: str, shape: tuple[int, ...], depth: int,
               lens: LensModel | None = None) -> np.ndarray:
    raw, frame_depth, _ = _read_frame(path, what)
    if frame_depth != depth:
        raise ValueError(f"{what} {Path(path).name} is {_kind(frame_depth)} but the photo is {_kind(depth)}; "
                         f"save the {what} like the photo")
    if raw.shape != shape:
        size = lambda s: f"{s[1]} x {s[0]}" + (" RGB" if len(s) == 3 else " grey")  # noqa: E731
        raise ValueError(f"{what} {Path(path).name} is {size(raw.shape)} but the photo is {size(shape)}; "
                         f"take the {what} with the same camera settings")
    return raw if lens is None else lens.undistort(raw, f"{what} {Path(path).name}")


def import_photo(path: str | Path, corners: object | MarkerSheet, half_width: float, resolution: int, *,
                 channel: Channel = "grey", bit_depth: int | None = None, response: Response = "linear",
                 gamma: float = 2.2, black_level: float = 0.0, dark: str | Path | None = None,
                 flat: str | Path | None = None, saturation: float = 0.98, supersample: int = 4,
                 max_dropped: float = 0.5, lens: LensModel | None = None) -> PhotoImport:
    """Photo of the caustic -> receiver image (1, n, n) and weights, every step recorded.

    corners: receiver corners as photo [col, row] in the order bottom-left, bottom-right,
    top-right, top-left, or the :class:`MarkerSheet` printed around the receiver, whose markers
    in the photo locate it (framework/lab/screen_markers.py); half_width: receiver half width W
    (scene units); resolution: n.
    channel: 'grey' (mean of R, G, B; default), 'red', 'green' (matches a 525 nm filter) or
    'blue'; ignored for grey photos. bit_depth: 8, 16 or None (either). response / gamma: see
    :func:`linearize`. black_level: offset in the photo's digital numbers (e.g. 512 of 65535;
    .npy: fraction of full scale), subtracted before linearising. dark / flat: paths of a dark
    frame (processed alike, subtracted) and a flat-field photo (processed alike, dark-subtracted,
    divided after normalising by its mean inside the receiver; its pixels below 1e-3 of that mean
    or saturated are unusable). saturation: raw value (fraction of full scale) at or above which a photo pixel is
    saturated in any used channel. Receiver pixels touching saturated or unusable photo pixels get
    weight 0; more than ``max_dropped`` of them is refused. lens: the camera's distortion
    (framework/lab/lens.py), undone on the photo, dark frame and flat field before anything is
    located or rectified (typed corners then refer to the undistorted photo); None: none.
    """
    raw, depth, read = _checked_frame(path, bit_depth)
    name = Path(path).name
    if depth == RAW_DEPTH and (black_level or response != "linear"):
        raise ValueError(f"photo {name} is a camera RAW file, read linearly with the file's black level; drop "
                         f"data.black_level={black_level:g} and data.response={response!r} (the defaults 0 and linear)")
    resolution, supersample = check_receiver_grid(resolution, half_width, supersample)
    if channel not in ("grey", "red", "green", "blue"):
        raise ValueError(f"data.channel={channel!r} must be 'grey', 'red', 'green' or 'blue'")
    checked_number(saturation, "data.saturation", above=0.0, most=1.0,
                   must="must be a fraction of full scale in (0, 1]", example="0.98")
    # the settings checked, the costly part: the lens undone and the receiver located
    raw, saturated_before = _undistorted(raw, lens, channel, saturation, f"photo {name}")
    located = None
    if isinstance(corners, MarkerSheet):
        sheet = corners
        located = detect_receiver(raw, sheet, f"photo {name}")
        corners = located.corners
    corners = check_corners(corners, raw.shape)
    full = FULL_SCALE.get(depth, 1)
    unit = "DN" if depth else "(fraction of full scale)"
    checked_number(black_level, "data.black_level", 0.0, below=full,
                   must=f"must lie in [0, {full}) {unit} for photo {name}")
    if not 0 <= max_dropped < 1:
        raise ValueError(f"max_dropped={max_dropped!r} must be a fraction in [0, 1)")
    linearize(np.zeros(1), response, gamma)  # refuses an unknown response
    linearize(np.zeros(1), "gamma", gamma)  # and a bad gamma, whatever the response
    if depth == 0 and response != "linear":  # (a RAW file was refused above)
        raise ValueError(f"photo {name} is a .npy array of linear values but data.response={response!r}; "
                         "set data.response=linear")
    height, width = raw.shape[:2]
    rgb = raw.ndim == 3
    steps = [f"read {name}: {read}"] + ([f"lens distortion undone ({lens.describe()})"] if lens else []) + (
        [located.describe(sheet)] if located else [])

    used = _select(raw, channel)
    saturated = (used >= saturation).any(axis=-1) | saturated_before
    if not (used > black_level / full).any():
        raise ValueError(f"photo {name} is all zero after subtracting data.black_level={black_level} {unit} "
                         f"(largest value {used.max() * full:.6g} {unit}); lower data.black_level or check the file")
    values = _linear_frame(raw, depth, channel, black_level, response, gamma)
    if black_level:
        steps.append(f"black level {black_level:g} {unit} subtracted")
    steps.append({"linear": "response linear (values kept)", "srgb": "inverse sRGB response applied",
                  "gamma": f"inverse response v ** {gamma:g} applied"}[response])
    if rgb:
        steps.append("channel grey = mean of linear R, G, B" if channel == "grey" else f"channel {channel} used")
    elif channel != "grey":
        steps.append(f"grey photo: data.channel={channel} ignored")

    dark_values = None
    if dark is not None:
        dark_values = _linear_frame(_read_like(dark, "dark frame", raw.shape, depth, lens), depth, channel, black_level,
                                    response, gamma)
        values = values - dark_values
        steps.append(f"dark frame {Path(dark).name} subtracted (mean {dark_values.mean():.4g})")

    h = homography(corners, float(half_width))
    unusable = np.zeros_like(saturated)
    if flat is not None:
        flat_raw = _read_like(flat, "flat field", raw.shape, depth, lens)
        flat_values = _linear_frame(flat_raw, depth, channel, black_level, response, gamma)
        if dark_values is not None:
            flat_values = flat_values - dark_values
        mean = float(flat_values[inside_receiver(h, (height, width), float(half_width))].mean())
        if not mean > 0:
            raise ValueError(f"flat field {Path(flat).name} has mean {mean:.4g} inside the receiver after the black "
                             "level and dark frame; it must be a bright, evenly lit photo of the screen")
        unusable = (flat_values < FLAT_FLOOR * mean) | (_select(flat_raw, channel) >= saturation).any(axis=-1)
        values = np.where(unusable, 0.0, values * mean / np.where(unusable, 1.0, flat_values))
        steps.append(f"flat field {Path(flat).name} divided (mean {mean:.4g} inside the receiver; "
                     f"{int(unusable.sum())} photo pixels unusable)")

    area = 0.5 * abs(float(np.sum(corners[:, 0] * np.roll(corners[:, 1], -1)
                                  - np.roll(corners[:, 0], -1) * corners[:, 1])))
    (ax, ay), (bx, by) = corners[1] - corners[0], corners[2] - corners[1]
    turn = ax * by - ay * bx  # < 0: the usual view (row axis points down), > 0: mirrored
    steps.append(f"homography from the corners: {np.sqrt(area) / resolution:.3g} photo px per receiver pixel"
                 + ("; the receiver is seen mirrored (camera behind the screen?)" if turn > 0 else ""))

    bad = saturated | unusable
    dropped = saturated_receiver_pixels(bad, h, resolution, float(half_width), supersample)
    n_dropped = int(dropped.sum())
    if n_dropped > max_dropped * resolution ** 2:
        raise ValueError(f"photo {name}: {n_dropped} of {resolution ** 2} receiver pixels "
                         f"({100 * n_dropped / resolution ** 2:.0f}%, more than {100 * max_dropped:.0f}%) touch "
                         f"{int(saturated.sum())} saturated photo pixels (raw >= data.saturation={saturation})"
                         + (f" or {int(unusable.sum())} unusable flat-field pixels" if unusable.any() else "")
                         + "; shorten the exposure or fix the flat field")
    left_out: dict[str, int] = {}
    if unusable.any():  # where the flat field is dark, no light is known to arrive: outside the lit region
        unlit = saturated_receiver_pixels(unusable & ~saturated, h, resolution, float(half_width), supersample)
        left_out["unlit"] = int(unlit.sum())
        steps.append(f"lit region (flat field above {FLAT_FLOOR:g} of its mean, not saturated): "
                     f"{100 * (1 - unlit.mean()):.1f}% of the receiver; its {left_out['unlit']} receiver pixels "
                     "outside it are left out (weight 0)")
    else:
        unlit = np.zeros((resolution, resolution), dtype=bool)
    left_out["saturated"] = int((dropped & ~unlit).sum())
    if saturated.any():
        steps.append(f"{int(saturated.sum())} saturated photo pixels (raw >= {saturation:g}) -> "
                     f"{left_out['saturated']} receiver pixels" + (" inside the lit region" if unusable.any() else "")
                     + " left out (weight 0)")
    else:
        steps.append(f"no saturated photo pixels (raw >= {saturation:g})")

    image = rectify(values, h, resolution, float(half_width), supersample)
    weights = (~dropped).astype(np.float64)[None]
    if not (image[weights > 0] > 0).any():
        raise ValueError(f"photo {name} gives an all-zero receiver image after the dark frame and flat field; "
                         "check the corners and the dark frame")
    steps.append(f"rectified to {resolution} x {resolution} receiver pixels, {supersample} x {supersample} "
                 "bilinear samples averaged per pixel")
    return PhotoImport(image=image, weights=weights, steps=steps, photo=values, corners=corners, homography=h,
                       bad_photo_pixels=bad, half_width=float(half_width), path=Path(path), left_out=left_out)
