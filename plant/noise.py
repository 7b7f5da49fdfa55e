"""Sensor noise models and per-stream random generators.

Model: ``reported = quantise(true + bias + N(mean, std))`` with
``quantise(x) = round(x / resolution) * resolution`` when ``resolution > 0``.
All four numbers are in the sensor's own units (m for lidar and GPS, rad for wheel
encoders, 0..255 intensity levels for a camera).

Webots' ``noise`` fields mean different things per device, so each has a constructor
(see the field notes, "Webots semantics"):

* Lidar ``noise``: std relative to ``maxRange`` -> :func:`webots_lidar` (std = noise * max_range).
* Camera ``noise``: per-channel, 1.0 == std 255 -> :func:`webots_camera`.
* PositionSensor ``noise``: absolute std in rad, per reading -> :func:`webots_position`.
* GPS ``noise``: absolute std in m -> :func:`webots_gps`.

The draws are counter-based: every noise value is a pure function of (run seed, robot,
stream, tick, index). A stream (e.g. robot1's ``lidar``) has a key (:func:`stream_key`);
:func:`normals` gives the standard normals of any number of (key, tick) rows in one call
of plant/kernels/noise.c, and :func:`frame_seed` seeds a camera frame's noise the same
way. So adding or removing a sensor, or a reader of a topic, never changes another value;
the same seed gives the same noise, run after run, across processes and hosts; and a
world's noise state is nothing but its tick.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from plant import kernels
from plant.image_law import alias_table, image_noise_law, image_noise_reference

__all__ = [
    "NoiseConfig",
    "NoiseModel",
    "stream_key",
    "normals",
    "normals_reference",
    "frame_seed",
    "parse_noise",
    "webots_lidar",
    "webots_camera",
    "webots_position",
    "webots_gps",
    "WEBOTS_SCALES",
    "alias_table",
    "image_noise_law",
    "image_noise_reference",
]


@dataclass(frozen=True)
class NoiseConfig:
    """Gaussian noise + bias + quantisation, in the sensor's own units."""

    std: float = 0.0
    mean: float = 0.0
    bias: float = 0.0
    resolution: float = 0.0          # quantisation step; 0 = none

    def __post_init__(self) -> None:
        for key in ("std", "mean", "bias", "resolution"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(f"noise {key} must be a number, got {v!r}")
            if not math.isfinite(float(v)):
                raise ValueError(f"noise {key} must be finite, got {v!r}")
        if self.std < 0:
            raise ValueError(f"noise std must be >= 0, got {self.std!r}")
        if self.resolution < 0:
            raise ValueError(f"noise resolution must be >= 0, got {self.resolution!r}")

    @property
    def is_zero(self) -> bool:
        """True when the model leaves values unchanged (apart from quantisation)."""
        return self.std == 0 and self.mean == 0 and self.bias == 0


# ----------------------------------------------------------------------------------
# Webots-style constructors
# ----------------------------------------------------------------------------------

def webots_lidar(noise: float, max_range: float) -> NoiseConfig:
    """Webots Lidar ``noise``: std dev relative to maxRange (m)."""
    _check_webots(noise)
    if not (max_range > 0 and math.isfinite(max_range)):
        raise ValueError(f"max_range must be a positive finite number, got {max_range!r}")
    return NoiseConfig(std=float(noise) * float(max_range))


def webots_camera(noise: float) -> NoiseConfig:
    """Webots Camera ``noise``: per-channel std dev, 1.0 == 255 intensity levels."""
    _check_webots(noise)
    return NoiseConfig(std=float(noise) * 255.0)


def webots_position(noise: float) -> NoiseConfig:
    """Webots PositionSensor ``noise``: absolute std dev in rad, per reading."""
    _check_webots(noise)
    return NoiseConfig(std=float(noise))


def webots_gps(noise: float) -> NoiseConfig:
    """Webots GPS ``noise``: absolute std dev in m."""
    _check_webots(noise)
    return NoiseConfig(std=float(noise))


def _check_webots(noise: Any) -> None:
    if isinstance(noise, bool) or not isinstance(noise, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(noise)) or noise < 0:
        raise ValueError(f"webots_noise must be a finite number >= 0, got {noise!r}")


#: How each sensor kind scales a Webots ``noise`` value into a std dev in its units.
#: Lidar needs its max range, so it is handled in :func:`parse_noise`.
WEBOTS_SCALES = {"camera": 255.0, "position": 1.0, "encoder": 1.0, "gps": 1.0}

_PLAIN_KEYS = ("std", "mean", "bias", "resolution")


def parse_noise(table: Mapping[str, Any] | None, sensor: str, *,
                max_range: float | None = None, where: str = "noise") -> NoiseConfig:
    """Build a :class:`NoiseConfig` from a plain dict (a TOML table).

    Two forms (not mixable for the std):
      ``{std = 0.01, mean = 0, bias = 0, resolution = 0}`` (any subset; sensor units), or
      ``{webots_noise = 0.2}`` (Webots meaning for ``sensor``; may be combined with
      ``mean``, ``bias``, ``resolution``).
    ``sensor``: ``"lidar"`` (needs ``max_range``), ``"camera"``, ``"position"``/``"encoder"``,
    ``"gps"``. ``where``: prefix for error messages (e.g. ``"world.toml:robot1.lidar.noise"``).
    None or ``{}`` means no noise. Raises ValueError naming the offending key.
    """
    if table is None:
        return NoiseConfig()
    if not isinstance(table, Mapping):
        raise ValueError(f"{where}: expected a table like {{std = 0.01}}, "
                         f"got {type(table).__name__}")
    allowed = set(_PLAIN_KEYS) | {"webots_noise"}
    for key in table:
        if key not in allowed:
            raise ValueError(f"{where}.{key}: unknown key; expected one of "
                             f"{', '.join(sorted(allowed))}")
    values: dict[str, float] = {}
    for key, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise ValueError(f"{where}.{key}: must be a number, got {v!r}")
        if not math.isfinite(float(v)):
            raise ValueError(f"{where}.{key}: must be finite, got {v!r}")
        if key in ("std", "webots_noise", "resolution") and v < 0:
            raise ValueError(f"{where}.{key}: must be >= 0, got {v!r}")
        values[key] = float(v)
    if "webots_noise" in values:
        if "std" in values:
            raise ValueError(f"{where}.webots_noise: give either std or webots_noise, not both")
        w = values.pop("webots_noise")
        if sensor == "lidar":
            if max_range is None:
                raise ValueError(f"{where}.webots_noise: lidar noise needs the lidar's max range")
            values["std"] = webots_lidar(w, max_range).std
        elif sensor in WEBOTS_SCALES:
            values["std"] = w * WEBOTS_SCALES[sensor]
        else:
            raise ValueError(f"{where}.webots_noise: no Webots meaning known for sensor "
                             f"{sensor!r}; use std instead")
    return NoiseConfig(**values)


# ----------------------------------------------------------------------------------
# Counter-based draws: a pure function of (key, tick, index)
# ----------------------------------------------------------------------------------

_M64 = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15
_TWO_PI = 2.0 * math.pi
_TWO_M53 = 1.0 / 9007199254740992.0
#: sets a frame's seed apart from the normals of the same key and tick
_FRAME_DOMAIN = 0xD1B54A32D192ED03


def _mix(z: int) -> int:
    """SplitMix64's finaliser (Steele, Lea and Flood 2014), on a Python int < 2**64."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    return z ^ (z >> 31)


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def stream_key(seed: int, robot: str, stream: str) -> int:
    """The key (a uint64, as a Python int) of the noise stream ``stream`` of ``robot`` in a
    run seeded ``seed``: SplitMix64's finaliser folded over the seed's 64-bit words and the
    four 64-bit words of ``sha256(f"{robot}/{stream}")``. The same in every process and
    Python version; another name or seed gives an unrelated key."""
    seed = _check_seed(seed)
    words = []
    while True:
        words.append(seed & _M64)
        seed >>= 64
        if not seed:
            break
    digest = hashlib.sha256(f"{robot}/{stream}".encode("utf-8")).digest()
    words += [int.from_bytes(digest[i:i + 8], "little") for i in range(0, 32, 8)]
    h = 0
    for w in words:
        h = _mix(((h ^ w) + _GOLDEN) & _M64)
    return h


def _row_seed(key: int, tick: int) -> int:
    return _mix((key + _mix((tick + _GOLDEN) & _M64)) & _M64)


def normals(keys, ticks, n: int, out: np.ndarray | None = None) -> np.ndarray:
    """Standard normals, float64 (len(keys), n): element ``[r, i]`` a pure function of
    ``(keys[r], ticks[r], i)``, so rows may be drawn together or apart, in any order, and
    the first n of a row are the same whatever n. ``keys``: uint64 (K,) (e.g. from
    :func:`stream_key`); ``ticks``: one int for every row or an int64 (K,). Drawn in one
    call by plant/kernels/noise.c (:func:`normals_reference` is its arithmetic in Python).
    ``out``: a float64 (K, n) C-contiguous array to fill (returned)."""
    keys = _integers(keys, np.uint64, "keys")
    if keys.ndim != 1:
        raise ValueError(f"keys must be one-dimensional, got shape {keys.shape}")
    ticks = _integers(ticks, np.int64, "ticks").reshape(-1)
    if ticks.size not in (1, keys.size):
        raise ValueError(f"ticks must be one int or one per key ({keys.size}), got {ticks.size}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    shape = (keys.size, int(n))
    if out is None:
        out = np.empty(shape)
    elif out.shape != shape or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float64 array of shape {shape}")
    return kernels.normals(keys, ticks, int(n), out)


def _integers(values, dtype, what: str) -> np.ndarray:
    """``values`` (an array, a list or one number) as a C-contiguous array of ``dtype``,
    every value an integer that fits it (ValueError naming ``what`` otherwise: numpy would
    truncate a float, and reads a list holding 2**63 as floats)."""
    if isinstance(values, np.ndarray):
        if values.dtype == dtype:
            return np.ascontiguousarray(values)
        if values.dtype.kind in "iu":
            info = np.iinfo(dtype)
            if values.size == 0 or (values.min() >= info.min and values.max() <= info.max):
                return np.ascontiguousarray(values, dtype=dtype)
        raise ValueError(f"{what} must be integers within {np.dtype(dtype).name}, got "
                         f"{values.dtype} values")
    flat = list(values) if isinstance(values, (list, tuple)) else [values]
    if any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in flat):
        raise ValueError(f"{what} must be integers, got {values!r}")
    try:
        return np.array(values, dtype=dtype)
    except OverflowError:
        raise ValueError(f"{what} must fit {np.dtype(dtype).name}, got {values!r}") from None


def normals_reference(key: int, tick: int, n: int) -> list[float]:
    """The n normals of ``key`` at ``tick``, in Python (math's log, sqrt, cos and sin call
    the same libm as the kernel; numpy's ufuncs may differ in the last bit): Box-Muller on
    two 53-bit uniforms from SplitMix64 counters, as plant/kernels/noise.c states."""
    s = _row_seed(int(key) & _M64, int(tick) & _M64)
    out: list[float] = []
    for i in range(0, n, 2):
        a = _mix((s + (i + 1) * _GOLDEN) & _M64)
        b = _mix((s + (i + 2) * _GOLDEN) & _M64)
        u1 = float((a >> 11) + 1) * _TWO_M53
        u2 = float(b >> 11) * _TWO_M53
        rad, t = math.sqrt(-2.0 * math.log(u1)), _TWO_PI * u2
        out.append(rad * math.cos(t))
        if i + 1 < n:
            out.append(rad * math.sin(t))
    return out


def frame_seed(key: int, tick: int) -> int:
    """The seed of a camera frame's noise (:func:`plant.kernels.image_noise`, itself
    counter-based given it) at ``tick`` for the camera stream's ``key``: a uint64 apart
    from every normal of the same key."""
    return _mix(_row_seed(int(key) & _M64, int(tick) & _M64) ^ _FRAME_DOMAIN)


# ----------------------------------------------------------------------------------
# Application
# ----------------------------------------------------------------------------------

class NoiseModel:
    """Applies a :class:`NoiseConfig` to the values of one noise stream (``key``, from
    :func:`stream_key`), or of several at once, one a row (``key`` a uint64 array (K,)).

    ``apply(x, tick)``:
      * float input: float64 ``quantise(x + (bias + mean) + Z std)``, Z the standard normals
        of (key, tick) (:func:`normals`), element i of ``x`` (C order) taking the i-th;
        ``inf``/``nan`` stay as they are. With several keys the first axis of ``x`` is the
        rows, row r drawn from ``key[r]`` at ``tick`` (one int, or one per row).
      * uint8 input (camera images, one key): the same per element (per channel), rounded
        and clipped to 0..255, returned as uint8. Without quantisation (``resolution`` 0,
        the usual case) the image is drawn by the C kernel plant/kernels/noise.c, seeded
        with :func:`frame_seed` of (key, tick): each channel gets ``clip(x + D, 0, 255)``
        with D an integer drawn from the law of ``rint(bias + mean + N(0, std))``
        (:func:`alias_table`), which is the law of ``clip(rint(x + bias + N(mean, std)))``
        for a whole level x. With quantisation the normals of (key, tick) are summed in
        float32 as stated.
      * other integer input: treated as float (returns float64).
    With ``std == 0`` nothing is drawn. The values depend on (key, tick) alone: applied
    twice they are the same, and a tick whose value nobody reads draws nothing.
    """

    def __init__(self, config: NoiseConfig, key) -> None:
        self.config = config
        keys = np.asarray(_check_keys(key), dtype=np.uint64)
        #: whether this model is several streams, one a row
        self.rows = keys.ndim == 1
        self.keys = np.ascontiguousarray(keys.reshape(-1))
        self.key = None if self.rows else int(keys)
        self._by_law = config.std > 0 and config.resolution == 0
        self._ahead: tuple[int, tuple, np.ndarray] | None = None   # (tick, shape, noise)
        self._call: tuple | None = None       # (n, buffer, its call's arguments): _drawn

    def select(self, idx) -> "NoiseModel":
        """The model of rows ``idx`` only (their own keys)."""
        if not self.rows:
            raise ValueError("select() takes rows of a model of several keys")
        return NoiseModel(self.config, self.keys[np.asarray(idx)])

    def normals(self, tick, shape: tuple[int, ...]) -> np.ndarray:
        """The standard normals ``apply`` adds (times std) to values of ``shape`` at
        ``tick``, float64: :func:`normals` of the keys, shaped like the values (a new
        array)."""
        shape = tuple(shape)
        if not self.rows and (type(tick) is int or isinstance(tick, np.integer)):
            return self._drawn(tick, shape).copy()
        return self._rows(tick, shape)

    def _rows(self, tick, shape: tuple[int, ...]) -> np.ndarray:
        if self.rows:
            if not shape or shape[0] != self.keys.size:
                raise ValueError(f"{self.keys.size} rows of noise, values of shape {shape}")
            n = int(np.prod(shape[1:], dtype=np.int64))
        else:
            n = int(np.prod(shape, dtype=np.int64))
        return normals(self.keys, tick, n).reshape(shape)

    def _drawn(self, tick, shape: tuple[int, ...]) -> np.ndarray:
        """:meth:`normals` into a buffer of this model's, reused call after call (read it
        before the next): one kernel call with the addresses taken once, as a sensor
        draws tick after tick (taking them costs more than drawing a few normals)."""
        if self.rows or (type(tick) is not int and not isinstance(tick, np.integer)):
            return self._rows(tick, shape)
        n = 1
        for d in shape:
            n *= d
        call = self._call
        if call is None or call[0] != n:
            buf, at = np.empty((1, n)), np.zeros(1, np.int64)
            call = self._call = (n, buf, at, kernels.normals_call(self.keys, at, n, buf))
        call[2][0] = tick
        call[3]()
        return call[1].reshape(shape)

    def prefetch_image(self, shape: tuple[int, ...], tick: int) -> None:
        """Draw the noise of an image of ``shape`` at ``tick`` now (e.g. while the plant
        waits for its nodes); an image drawn by the C kernel (no quantisation) has nothing
        to draw ahead. The image is the same with or without it."""
        if self.config.std > 0 and not self._by_law:
            self._take_image_noise(tuple(shape), int(tick), keep=True)

    def _take_image_noise(self, shape: tuple, tick: int, keep: bool = False) -> np.ndarray:
        ahead, self._ahead = self._ahead, None
        if ahead is not None and ahead[0] == tick and ahead[1] == shape:
            noise = ahead[2]
        else:
            noise = self.normals(tick, shape).astype(np.float32)
            noise *= np.float32(self.config.std)
        if keep:
            self._ahead = (tick, shape, noise)
        return noise

    def image_draw(self, tick: int) -> tuple[int, tuple[np.ndarray, np.ndarray]] | None:
        """``(frame seed, alias table)``: the arguments of :func:`plant.kernels.image_noise`
        with which :meth:`apply` draws an image's noise at ``tick``, or None when it does not
        draw it so (no noise, quantisation, several keys)."""
        if not self._by_law or self.rows:
            return None
        c = self.config
        return frame_seed(self.key, tick), alias_table(float(c.std), float(c.bias + c.mean))

    def apply(self, x, tick):
        arr = np.asarray(x)
        c = self.config
        if arr.dtype == np.uint8:
            if c.is_zero and c.resolution == 0:
                return arr.copy()
            if self.rows:
                raise ValueError("an image's noise takes one key")
            # Images: single precision is plenty for 0..255 and several times faster.
            offset = np.float32(c.bias + c.mean)
            if self._by_law:
                # x + D, D ~ rint(offset + N(0, std)), clipped: one pass of the C kernel
                img = np.empty(arr.shape, dtype=np.uint8)
                kernels.image_noise(np.ascontiguousarray(arr), *self.image_draw(tick), img)
                return img
            if c.std > 0:
                # (x + offset) + noise, summed into the noise's own buffer
                noise = self._take_image_noise(arr.shape, int(tick))
                out = np.add(arr, offset, dtype=np.float32, out=np.empty_like(noise)) \
                    if offset else arr
                out = np.add(noise, out, out=noise, dtype=np.float32)
            else:
                out = arr.astype(np.float32)
                out += offset
            if c.resolution > 0:
                out = np.round(out / np.float32(c.resolution)) * np.float32(c.resolution)
            np.rint(out, out=out)
            np.clip(out, 0, 255, out=out)
            return out.astype(np.uint8)
        out = arr.astype(np.float64) + (c.bias + c.mean)
        if c.std > 0:
            out = out + self._drawn(tick, arr.shape) * c.std
        if c.resolution > 0:
            with np.errstate(invalid="ignore"):
                out = np.where(np.isfinite(out), np.round(out / c.resolution) * c.resolution, out)
        return out

    __call__ = apply


def _check_keys(key):
    """``key`` as given, checked: an int in [0, 2**64) or a 1-D array of uint64."""
    if isinstance(key, np.ndarray):
        if key.ndim > 1 or (key.dtype != np.uint64 and not (
                np.issubdtype(key.dtype, np.integer) and (key >= 0).all())):
            raise ValueError(f"keys must be a 1-D array of uint64, got {key.dtype} {key.shape}")
        return key
    if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or not 0 <= key <= _M64:
        raise ValueError(f"a noise key is an integer in [0, 2**64), got {key!r}")
    return int(key)
