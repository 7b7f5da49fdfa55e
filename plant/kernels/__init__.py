"""The plant's compiled kernels (C, built into plant/kernels/build/ by ``make setup`` in a
clone, or by the wheel's build),
loaded with ctypes: the lidar's sweep (:func:`lidar_scan`), the camera's per-pixel work, the
kinematic world's tick (:func:`kinematic_step`), a world's commands through its drive
limiters and motion noise (:func:`drive_commands_call`), and the ticks of one-robot worlds an
environment steps (:func:`ticks`, :func:`tick_part`: drive limiters, command and encoder
noise, kinematic step, dead reckoning; plant/kernels/drive.c and ticks.c).

The numpy code of :mod:`plant.raycast` stays as the reference the tests compare the
kernels with, value for value. There is no silent fallback: without the library the
sensors raise :class:`KernelsMissing`, which says how to build it.
"""
from __future__ import annotations

import ctypes
import sys
import threading
from functools import lru_cache
from pathlib import Path

import numpy as np


__all__ = ["KernelsMissing", "library", "lidar_scan", "camera_render", "camera_wide",
           "noise_wide", "image_noise", "normals",
           "ptr",
           "kinematic_step", "clearances", "ticks",
           "tick_part", "ticks_scans", "ticks_truths",
           "ticks_observe", "sense_call", "observe_kinematic_call", "quaternions",
           "quaternions_call", "observe_rows_call", "poses_call", "lidar_noise", "drive_commands_call"]

ABI = 4
CAMERA_ABI = 3
NOISE_ABI = 3
DRIVE_ABI = 2
KINEMATIC_ABI = 2
TICKS_ABI = 7
SENSE_ABI = 3
#: where ``python -m plant.kernels.build`` puts the library
BUILD_DIR = Path(__file__).resolve().parent / "build"
LIBRARY = "libplant_kernels" + (".dylib" if sys.platform == "darwin" else ".so")
HOW_TO_BUILD = ("`make setup` in a clone, `python -m plant.kernels.build`, or reinstall "
                "diffbot-cosim (its wheel's build compiles them)")


class KernelsMissing(RuntimeError):
    pass


_P = ctypes.c_void_p
_I = ctypes.c_int64
_D = ctypes.c_double


@lru_cache(maxsize=1)
def library() -> ctypes.CDLL:
    """The loaded kernels (KernelsMissing if they are not built, or are out of date)."""
    return load(BUILD_DIR / LIBRARY)


def load(path: Path) -> ctypes.CDLL:
    """Load the kernels' library at ``path`` and declare its functions."""
    if not path.is_file():
        raise KernelsMissing(f"the plant's C kernels are not built ({path} is missing): run "
                             f"{HOW_TO_BUILD}")
    lib = ctypes.CDLL(str(path))
    for name, want in (("plant_lidar_abi", ABI), ("plant_camera_abi", CAMERA_ABI),
                       ("plant_noise_abi", NOISE_ABI), ("plant_drive_abi", DRIVE_ABI),
                       ("plant_kinematic_abi", KINEMATIC_ABI), ("plant_ticks_abi", TICKS_ABI),
                       ("plant_sense_abi", SENSE_ABI)):
        abi = getattr(lib, name)() if hasattr(lib, name) else None
        if abi != want:
            raise KernelsMissing(f"{path} is out of date ({name} {abi}, expected {want}): "
                                 f"{HOW_TO_BUILD}")
    lib.plant_camera_render.restype = None
    lib.plant_camera_render.argtypes = ([_P] * 4 + [_I, _P, _I, _P, _P, _I, _I, _D, _D, _D, _P, _P,
                                         _D, _D] + [_P] * 5 + [ctypes.c_uint64, _I, _P, _P])
    lib.plant_camera_wide.restype = ctypes.c_int
    lib.plant_camera_wide.argtypes = [ctypes.c_int]
    lib.plant_noise_wide.restype = ctypes.c_int
    lib.plant_noise_wide.argtypes = [ctypes.c_int]
    lib.plant_image_noise.restype = None
    lib.plant_image_noise.argtypes = [_P, _I, ctypes.c_uint64, _I, _P, _P, _P]
    lib.plant_normals.restype = None
    lib.plant_normals.argtypes = [_I, _P, _P, _I, _I, _P]
    lib.plant_kinematic_step.restype = ctypes.c_int
    lib.plant_kinematic_step.argtypes = ([_I, _D] + [_P] * 8 + [_I] + [_P] * 4 + [_I]
                                         + [_P] * 3 + [_D, _D, _I])
    lib.plant_ticks.restype = ctypes.c_int64
    lib.plant_ticks.argtypes = [_I, _I, _P, _P]
    lib.plant_tick_part.restype = ctypes.c_int64
    lib.plant_tick_part.argtypes = [_I, _I, _P, _P]
    lib.plant_ticks_scans.restype = None
    lib.plant_ticks_truths.restype = None
    lib.plant_ticks_observe.restype = None
    lib.plant_ticks_observe.argtypes = [_I, _P, _P, _P, _P, _D, _P, _P]
    lib.plant_ticks_truths.argtypes = [_I, _P, _P]
    lib.plant_ticks_scans.argtypes = [_I, _P, _P, _P, _P]
    lib.plant_ticks_count.restype = ctypes.c_int64
    lib.plant_ticks_count.argtypes = []
    lib.plant_clearances.restype = None
    lib.plant_clearances.argtypes = [_I, _P, _I] + [_P] * 4 + [_I] + [_P] * 4
    lib.plant_sense.restype = None
    lib.plant_sense.argtypes = [_I] + [_P] * 12 + [_I, _I, _P]
    lib.plant_observe_kinematic.restype = None
    lib.plant_observe_kinematic.argtypes = [_I] + [_P] * 12
    lib.plant_quaternions.restype = None
    lib.plant_quaternions.argtypes = [_I, _P, _P]
    lib.plant_observe_rows.restype = None
    lib.plant_observe_rows.argtypes = [_I] + [_P] * 7
    lib.plant_poses.restype = None
    lib.plant_poses.argtypes = [_I, _P, _P, _P, _I, _I, _P]
    lib.plant_drive_commands.restype = None
    lib.plant_drive_commands.argtypes = [_I, _I] + [_P] * 10
    lib.plant_lidar_noise.restype = None
    lib.plant_lidar_noise.argtypes = [_I, _I, _P, _P, _P, _I, _D, _D, _D, _P, _P]
    lib.plant_lidar_scan.restype = None
    lib.plant_lidar_scan.argtypes = ([_P] * 7 + [_I, _I, _I] + [_P] * 5 + [_D] * 4
                                     + [_P, _P, _I])
    return lib


def ptr(a: np.ndarray | int) -> int:
    """The address of a C-contiguous array's data (checked), or ``a`` if it is an address
    already: a caller that calls a kernel tick after tick with the same arrays takes their
    addresses once (an address costs ~4 us) and keeps the arrays alive."""
    if type(a) is int:
        return a
    assert a.flags.c_contiguous, "kernel arrays must be C-contiguous"
    return a.ctypes.data


def lidar_scan(scene_arrays: tuple[int, ...], n_shapes: int, poses: np.ndarray,
               dirs: np.ndarray, skip_owner: np.ndarray, a0: float, inc: float,
               min_range: float, max_range: float, first_shape: np.ndarray | None = None,
               last_shape: np.ndarray | None = None) -> np.ndarray:
    """(G, n) ranges of G fans of n rays (plant/kernels/lidar.c). ``scene_arrays``: the
    addresses of the scene's (centres, rotations, halves, quadrics, rr, radii, owner ids)
    (:meth:`plant.raycast.Scene.kernel_arrays`); ``poses`` (G, 4, 4) the sensors' world
    poses, ``dirs`` (G, n, 3) their rays, float64 and C-contiguous; ``skip_owner`` (G,)
    int64 the owner id each fan ignores (-1: none); ``first_shape``/``last_shape`` (G,)
    int64: the shapes [first, last) each fan sees (None: all)."""
    g, n = dirs.shape[0], dirs.shape[1]
    out = np.empty((g, n))
    work = np.empty(3 * n)
    library().plant_lidar_scan(
        *scene_arrays, n_shapes, g, n, ptr(poses), ptr(dirs), ptr(skip_owner),
        None if first_shape is None else ptr(first_shape),
        None if last_shape is None else ptr(last_shape), a0, inc, min_range, max_range,
        out.ctypes.data, work.ctypes.data, 1)
    return out


def camera_render(scene, todo: np.ndarray, cam: np.ndarray, light: np.ndarray, w: int, h: int,
                  f: float, cx: float, cy: float, xy: np.ndarray | None, bounds: np.ndarray,
                  near: float, far: float, lut: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
                  sid: np.ndarray, lam: np.ndarray, noise: tuple | None = None) -> None:
    """Fill ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 and ``sid`` (H, W) int64 with
    the picture of ``scene``'s shapes ``todo`` (int64) seen from ``cam`` (the optical
    frame's rotation, row-major, then its origin: 12 doubles); ``lam``: scratch of
    W H + W + H doubles. ``noise``: None, or ``(seed, (thresholds, values))`` of
    :func:`image_noise` drawn over ``rgb`` in the same call. plant/kernels/camera.c."""
    seed, thr, vals = (0, None, None) if noise is None else (noise[0], *noise[1])
    library().plant_camera_render(
        scene.centers.ctypes.data, scene.rotations.ctypes.data, *scene.const_ptrs()[:2],
        len(scene), ptr(todo), todo.size, ptr(cam), ptr(light), w, h, f, cx, cy,
        None if xy is None else ptr(xy), ptr(bounds), near, far, ptr(lut), ptr(rgb),
        ptr(depth), ptr(sid), ptr(lam), seed, 0 if thr is None else thr.size,
        None if thr is None else ptr(thr), None if vals is None else ptr(vals))


def camera_wide(mode: int | None = None) -> bool:
    """Whether the camera's box test runs four pixels at a time (AVX2 on x86-64; the same
    values as two at a time). ``mode`` 0 turns that off, -1 back on where available
    (the tests compare the two)."""
    return bool(library().plant_camera_wide(1 if mode is None else int(mode)))


def noise_wide(mode: int | None = None) -> bool:
    """Whether the image noise is drawn eight elements at a time (AVX2 on x86-64; the same
    bytes as two at a time). ``mode`` 0 turns that off, -1 back on where available (the
    tests compare the two)."""
    return bool(library().plant_noise_wide(1 if mode is None else int(mode)))


def camera_work(w: int, h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """This thread's depth, shape and scratch buffers for a W x H frame, reused."""
    cache = getattr(_local, "camera", None)
    if cache is None:
        cache = _local.camera = {}
    bufs = cache.get((w, h))
    if bufs is None:
        if len(cache) > 8:
            cache.clear()
        bufs = cache[(w, h)] = (np.empty((h, w), dtype=np.float32),
                                np.empty((h, w), dtype=np.intp), np.empty(w * h + w + h))
    return bufs


def image_noise(img: np.ndarray, seed: int, table: tuple[np.ndarray, np.ndarray],
                out: np.ndarray) -> None:
    """``out`` = clip(``img`` + D, 0, 255) per element, D drawn from the alias ``table``
    ``(thresholds uint32 (K,), values + 255 uint16 (K, 2))`` (:func:`plant.noise.alias_table`)
    with the frame's numbers from ``seed`` (plant/kernels/noise.c): ``img`` and ``out``
    uint8, C-contiguous, of one size."""
    assert img.size == out.size and img.dtype == out.dtype == np.uint8
    thr, vals = table
    library().plant_image_noise(ptr(img), img.size, seed, thr.size, ptr(thr), ptr(vals),
                                ptr(out))


def normals(keys: np.ndarray, ticks: np.ndarray, n: int, out: np.ndarray) -> np.ndarray:
    """``out`` (K, n) float64, C-contiguous: row r the standard normals 0..n-1 of the key
    ``keys[r]`` (uint64 (K,)) at the tick ``ticks[r]`` (int64 (K,), or (1,) for every row)
    (plant/kernels/noise.c; :func:`plant.noise.normals` checks the arguments)."""
    k = keys.shape[0]
    assert keys.dtype == np.uint64 and ticks.dtype == np.int64 and ticks.size in (1, k)
    assert out.shape == (k, n) and out.dtype == np.float64
    if k and n:
        library().plant_normals(k, ptr(keys), ptr(ticks), int(ticks.size == k), n,
                                ptr(out))
    return out


def normals_call(keys: np.ndarray, ticks: np.ndarray, n: int, out: np.ndarray):
    """:func:`normals` of these arrays as a function of no arguments, their addresses taken
    once (the caller keeps the arrays alive and changes their values in place)."""
    k = keys.shape[0]
    assert keys.dtype == np.uint64 and ticks.dtype == np.int64 and ticks.size in (1, k)
    assert out.shape == (k, n) and out.dtype == np.float64
    fn = library().plant_normals
    args = (k, ptr(keys), ptr(ticks), int(ticks.size == k), n, ptr(out))
    return lambda: fn(*args)


Array = np.ndarray | int      # an array, or its address (:func:`ptr`)


def kinematic_step(n: int, tick_s: float, targets: np.ndarray, robots: tuple[int, ...],
                   statics: tuple[int, ...], foot_r: float, centre_x: float, pairs: bool) -> None:
    """One tick of ``n`` kinematic robots (plant/kernels/kinematic.c; the reference:
    :func:`plant.kinematic.reference_step`): ``targets`` (n, 2) float64, C-contiguous, the
    wheel-speed targets; ``robots`` the addresses of their arrays (radius, separation,
    world, pose, wheels, speeds, vel; the last four updated) and ``statics`` the footprint
    test's (:meth:`plant.footprint.Footprints.kernel_args`), taken once by the caller, which
    keeps the arrays alive; ``pairs``: some world has two robots."""
    assert targets.shape == (n, 2) and targets.dtype == np.float64
    if library().plant_kinematic_step(n, tick_s, ptr(targets), *robots, *statics, foot_r,
                                      centre_x, int(pairs)):
        raise MemoryError("plant_kinematic_step: out of memory")


def ticks(n: int, most: int, slots: Array, params: Array) -> int:
    """Up to ``most`` control ticks of ``n`` robots in kinematic worlds (R a world: the
    ``robots`` slot) in one call (plant/kernels/ticks.c: the drive limiters, command noise,
    kinematic step, encoders and dead reckoning of each): ``slots`` the int64 block of addresses and counts, ``params``
    the double block, in the order ticks.c names them (or their addresses). The ticks
    made: fewer when a lidar came due."""
    made = library().plant_ticks(n, most, ptr(slots), ptr(params))
    if made < 0:
        raise MemoryError("plant_ticks: out of memory")
    return made


def tick_part(n: int, part: int, slots: Array, params: Array) -> int:
    """Half a control tick of ``n`` robots in worlds another engine steps (DART), as
    :func:`ticks` makes whole ones: ``part`` 0 the commands (into the targets' slot), 1
    what follows the step (the engine's wheel angles put in the wheels' slot first):
    whether some world's lidar is due."""
    return library().plant_tick_part(n, part, ptr(slots), ptr(params))


def ticks_scans(rows: np.ndarray, exact: np.ndarray, slots: Array, params: Array) -> None:
    """The scans of the robots ``rows`` (int64 (g,)) whose lidars :func:`ticks` found due,
    from their exact ranges ``exact`` (g, rays) float64, C-contiguous (plant/kernels/ticks.c:
    each world's lidar noise at its own tick, as :func:`lidar_noise` draws it, and the
    observation's clip), into the arrays ``slots`` names."""
    assert rows.dtype == np.int64 and rows.flags.c_contiguous and exact.dtype == np.float64
    assert exact.flags.c_contiguous and exact.shape[0] == rows.size
    library().plant_ticks_scans(rows.size, rows.ctypes.data, exact.ctypes.data, ptr(slots),
                                ptr(params))


def ticks_truths(pose: np.ndarray) -> np.ndarray:
    """The true (x, y, yaw), a new (n, 3) array, of kinematic robots at ``pose`` (n, 3)
    float64, C-contiguous, as their ``ground_truth`` messages give them back
    (plant/kernels/ticks.c: :func:`diffbot.envs.obsmath.truths`' arithmetic)."""
    assert pose.ndim == 2 and pose.shape[1] == 3 and pose.dtype == np.float64
    assert pose.flags.c_contiguous
    out = np.empty((len(pose), 3))
    library().plant_ticks_truths(len(pose), pose.ctypes.data, out.ctypes.data)
    return out


def ticks_observe(pose: np.ndarray, vel: np.ndarray, goal: np.ndarray, odom_high: np.ndarray,
                  goal_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The odometry (n, 5) and goal (n, 2) float32 parts of n robots' Avoid observations
    from their dead-reckoned ``pose`` (n, 3), velocity ``vel`` (n, 2) and ``goal`` (n, 2),
    float64, C-contiguous, clipped to +-``odom_high`` (5,) float32 and +-``goal_limit``
    (plant/kernels/ticks.c: :func:`diffbot.envs.obsmath.observation`'s arithmetic)."""
    n = len(pose)
    for a, k in ((pose, 3), (vel, 2), (goal, 2)):
        assert a.shape == (n, k) and a.dtype == np.float64 and a.flags.c_contiguous
    assert odom_high.shape == (5,) and odom_high.dtype == np.float32
    assert odom_high.flags.c_contiguous
    odom, out = np.empty((n, 5), np.float32), np.empty((n, 2), np.float32)
    library().plant_ticks_observe(n, pose.ctypes.data, vel.ctypes.data, goal.ctypes.data,
                                  odom_high.ctypes.data, float(goal_limit), odom.ctypes.data,
                                  out.ctypes.data)
    return odom, out


def clearances(pts: np.ndarray, statics: tuple) -> np.ndarray:
    """:meth:`plant.footprint.Footprints.clearances` of the points ``pts`` (M, 2) float64,
    C-contiguous (plant/kernels/kinematic.c; ``statics``: the test's
    :meth:`~plant.footprint.Footprints.kernel_args`): a new (M,) array."""
    assert pts.ndim == 2 and pts.shape[1] == 2 and pts.dtype == np.float64
    out = np.empty(len(pts))
    library().plant_clearances(len(pts), ptr(pts), *statics, ptr(out))
    return out


def sense_call(n: int, arrays: tuple[int, ...], at: np.ndarray, read: np.ndarray,
               out: np.ndarray):
    """``f(tick, t_ns)``: plant/kernels/sense.c's plant_sense of ``n`` robots, writing the
    stamps and values of their read joint_states, gps and ground_truth (``read`` uint8
    (n, 3)) into ``out`` (uint8, its templates written in) at the places ``at`` (int64
    (n, 8)). ``arrays``: the addresses of tf, quaternion, v, w, enc_pos, enc_vel, the
    encoders' keys and laws, the GPS's keys and laws (as sense.c orders them), taken once;
    the caller keeps every array alive and changes their values in place."""
    assert at.shape == (n, 8) and at.dtype == np.int64 and read.shape == (n, 3)
    assert read.dtype == np.uint8 and out.dtype == np.uint8 and len(arrays) == 10
    # the bytes each place starts: a stamp (after the 4-byte header), 2 + 2, 1 stamp, 3, a
    # stamp, 7, 6 doubles
    ends = at + np.array([12, 16, 16, 12, 24, 12, 56, 48], np.int64)
    if n and (int(at.min()) < 0 or int(ends.max()) > out.size):
        raise ValueError("plant_sense: the places lie outside the buffer")
    fn = library().plant_sense
    head = (n, *arrays, ptr(at), ptr(read))
    tail = ptr(out)
    return lambda tick, t_ns: fn(*head, tick, t_ns, tail)


def observe_kinematic_call(n: int, kin: tuple[np.ndarray, ...], data: tuple[np.ndarray, ...]):
    """``f()``: plant/kernels/sense.c's plant_observe_kinematic of ``n`` robots: ``kin`` their
    (pose, vel, wheels, speeds, radius), ``data`` the core's (tf, yaw, quaternion, v, w,
    enc_pos, enc_vel) of one world, float64, C-contiguous (addresses taken once)."""
    shapes = ((n, 3), (n, 2), (n, 2), (n, 2), (n,), (n, 4, 4), (n,), (n, 4), (n,), (n,),
              (n, 2), (n, 2))
    for a, shape in zip((*kin, *data), shapes):
        assert a.shape == shape and a.dtype == np.float64, (a.shape, shape)
    fn = library().plant_observe_kinematic
    args = (n, *(ptr(a) for a in (*kin, *data)))
    return lambda: fn(*args)


def quaternions(tf: np.ndarray, out: np.ndarray) -> None:
    """``out`` (n, 4) = :func:`plant.sim.rotation_to_quaternion` of each of ``tf`` (n, 4, 4),
    float64, C-contiguous (plant/kernels/sense.c)."""
    quaternions_call(tf, out)()


def quaternions_call(tf: np.ndarray, out: np.ndarray):
    """:func:`quaternions` of these arrays as a function of no arguments, their addresses
    taken once (the caller keeps them alive and changes their values in place)."""
    n = tf.shape[0]
    assert tf.shape == (n, 4, 4) and out.shape == (n, 4)
    assert tf.dtype == out.dtype == np.float64 and tf.flags.c_contiguous and out.flags.c_contiguous
    fn, args = library().plant_quaternions, (n, ptr(tf), ptr(out))
    return lambda: fn(*args)


def observe_rows_call(rows: np.ndarray, data: tuple[np.ndarray, ...]):
    """``f()``: plant/kernels/sense.c's plant_observe_rows: a dynamic world's state ``rows``
    (n, 26) (:meth:`plant.sim.Simulation.read_state`'s) into the core's ``data`` (tf (n, 4,
    4), quaternion (n, 4), v, w (n,), enc_pos, enc_vel (n, 2)) of one world, float64,
    C-contiguous (addresses taken once: the caller writes each tick's rows into ``rows``)."""
    n = rows.shape[0]
    shapes = ((n, 26), (n, 4, 4), (n, 4), (n,), (n,), (n, 2), (n, 2))
    for a, shape in zip((rows, *data), shapes):
        assert a.shape == shape and a.dtype == np.float64, (a.shape, shape)
    fn = library().plant_observe_rows
    args = (n, *(ptr(a) for a in (rows, *data)))
    return lambda: fn(*args)


def poses_call(tf: np.ndarray, quat: np.ndarray, at: np.ndarray, out: np.ndarray):
    """``f(sec, nanosec)``: plant/kernels/sense.c's plant_poses: each robot's stamp and pose
    (``tf`` (n, 4, 4), ``quat`` (n, 4), float64) written into ``out`` (uint8, the message's
    template) at ``at`` (int64 (n, 2): its stamp's and its transform's first bytes),
    C-contiguous (addresses taken once: the caller keeps the arrays alive)."""
    n = tf.shape[0]
    assert tf.shape == (n, 4, 4) and quat.shape == (n, 4) and at.shape == (n, 2)
    assert tf.dtype == quat.dtype == np.float64 and at.dtype == np.int64
    assert out.dtype == np.uint8
    if n and (int(at.min()) < 0 or int(at[:, 0].max()) + 8 > out.size
              or int(at[:, 1].max()) + 56 > out.size):
        raise ValueError("plant_poses: the places lie outside the buffer")
    fn = library().plant_poses
    head, tail = (n, ptr(tf), ptr(quat), ptr(at)), ptr(out)
    return lambda sec, nanosec: fn(*head, sec, nanosec, tail)


def drive_commands_call(worlds: int, n: int, tick: np.ndarray, limits: np.ndarray,
                        std: np.ndarray, keys: np.ndarray, kind: np.ndarray, cmd: np.ndarray,
                        v: np.ndarray, w: np.ndarray, wheels: np.ndarray,
                        targets: np.ndarray):
    """``f()``: plant/kernels/drive.c's plant_drive_commands of ``n`` robots in each of
    ``worlds`` worlds: the commands filed (``kind`` int64 (W, n): 0 none, 1 a twist, 2
    wheel speeds; ``cmd`` (W, n, 2) their values) through the limiters (``limits`` (n, 8),
    :func:`plant.core.drive.limits_of`; their state ``v``, ``w`` (W, n), ``wheels``
    (W, n, 2), updated) and the motion noise (``std`` (n,), ``keys`` uint64 (W, n), at
    ``tick`` int64 (W,): each world's tick, set before each call) into ``targets``
    (W, n, 2). Float64 unless said, C-contiguous; the addresses are taken once: the caller
    keeps the arrays alive and changes their values in place."""
    shapes = ((tick, (worlds,), np.int64), (limits, (n, 8), np.float64),
              (std, (n,), np.float64), (keys, (worlds, n), np.uint64),
              (kind, (worlds, n), np.int64), (cmd, (worlds, n, 2), np.float64),
              (v, (worlds, n), np.float64), (w, (worlds, n), np.float64),
              (wheels, (worlds, n, 2), np.float64), (targets, (worlds, n, 2), np.float64))
    for a, shape, dtype in shapes:              # (one world's rows: (n, ...) for (1, n, ...))
        ok = a.size == int(np.prod(shape)) and a.shape[-1:] == shape[-1:]
        assert ok and a.dtype == dtype and a.flags.c_contiguous, (a.shape, a.dtype, shape, dtype)
    fn = library().plant_drive_commands
    args = (worlds, n, *(ptr(a) for a, _, _ in shapes))
    return lambda: fn(*args)


def lidar_noise(exact: np.ndarray, keys: np.ndarray, laws: np.ndarray, tick: int, lo: float,
                hi: float, q: float) -> np.ndarray:
    """The reported ranges, a new (g, n) float32 array, of ``exact`` (g, n) float64: row r
    with the noise of ``keys[r]`` (uint64) and ``laws[r]`` (std, mean, bias, resolution) at
    ``tick``, clipped to [lo, hi] and quantised by ``q`` (plant/kernels/sense.c; the
    arithmetic of :func:`plant.lidar.apply_noise`)."""
    g, n = exact.shape
    assert exact.dtype == np.float64 and exact.flags.c_contiguous
    assert keys.shape == (g,) and keys.dtype == np.uint64 and keys.flags.c_contiguous
    assert laws.shape == (g, 4) and laws.dtype == np.float64 and laws.flags.c_contiguous
    out = np.empty((g, n), np.float32)
    if g and n:
        work = np.empty(n)
        library().plant_lidar_noise(g, n, ptr(exact), ptr(keys), ptr(laws), int(tick), lo, hi,
                                    q, ptr(work), ptr(out))
    return out


class LidarWork:
    """Buffers of one call shape (G fans of n rays), reused call after call with their
    addresses taken once (an address costs more than the kernel's work on a small fan):
    ``poses`` (G, 4, 4), ``dirs`` (G, n, 3), ``skip`` (G,) int64, ``out`` (G, n), and the
    kernel's scratch for ``threads`` threads (the fans split between them: the same
    ranges)."""

    def __init__(self, g: int, n: int, threads: int = 1) -> None:
        self.poses = np.zeros((g, 4, 4))
        self.dirs = np.zeros((g, n, 3))
        self.skip = np.zeros(g, dtype=np.int64)
        self.out = np.zeros((g, n))
        self.work = np.zeros(3 * n * threads)
        self.g, self.n, self.threads = g, n, threads
        self.ptrs = tuple(a.ctypes.data for a in (self.poses, self.dirs, self.skip))
        self.out_ptrs = (self.out.ctypes.data, self.work.ctypes.data, threads)


_local = threading.local()


def lidar_work(g: int, n: int, threads: int = 1) -> LidarWork:
    """This thread's buffers for G fans of n rays, cast on up to ``threads`` threads."""
    cache = getattr(_local, "lidar", None)
    if cache is None:
        cache = _local.lidar = {}
    ws = cache.get((g, n, threads))
    if ws is None:
        if len(cache) > 16:
            cache.clear()
        ws = cache[(g, n, threads)] = LidarWork(g, n, threads)
    return ws


def lidar_scan_work(scene_arrays: tuple[int, ...], n_shapes: int, ws: LidarWork, a0: float,
                    inc: float, min_range: float, max_range: float) -> np.ndarray:
    """:func:`lidar_scan` of the fans filled into ``ws`` (all shapes for every fan): a new
    (G, n) array of ranges."""
    library().plant_lidar_scan(*scene_arrays, n_shapes, ws.g, ws.n, *ws.ptrs, None, None,
                               a0, inc, min_range, max_range, *ws.out_ptrs)
    return ws.out.copy()
