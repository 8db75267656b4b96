"""Dataset manifest (``dataset.yaml``): which file holds each stream, in which format, frame and clock.

A plain KITTI raw drive folder (one holding ``oxts/``) needs no manifest: its OXTS packets give the
IMU, the GNSS and the ground truth; nor does a plain EuRoC / TUM-VI folder (``mav0/imu0``): its IMU and ground
truth. Formats beyond KITTI's own (EuRoC, generic CSV, ROS bags) are registered in :mod:`.formats`. A pose stream
in any sensor frame gives ``frame: <name>`` and ``T_imu_<name>`` (the sensor frame's pose in the IMU frame). See
the README's "Dataset manifest" and "Your own data" sections for every key.
"""

from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import ConfigError, DataFormatError, FusionEvalError
from ..geo import MAX_ORIGIN_DISTANCE_M, great_circle_m
from .. import yaml_lines
from ..yaml_lines import at
from ..so3 import make_T, matrix_to_quat_xyzw
from ..types import Dataset, PoseSeries
from . import kitti_oxts, kitti_poses, plausible
from .formats import for_stream
from .streams import ReadContext, StreamSpec

log = logging.getLogger(__name__)

STREAMS = ("imu", "gnss", "lidar", "groundtruth", "odometer")      # their formats: the registry (.formats)
_POSE_KEYS = {"frame", "T_cam0_imu", "T_cam0_velo", "T_velo_imu", "times"}
STREAM_KEYS = {
    "imu": {"format", "path", "time_offset_s", "gyro_lag_s", "accel_lag_s"},
    "gnss": {"format", "path", "time_offset_s", "std_m", "degrade"},
    "groundtruth": {"format", "path", "time_offset_s"} | _POSE_KEYS,
    "lidar": {"format", "path", "time_offset_s", "anchor"} | _POSE_KEYS,
    "odometer": {"format", "path", "time_offset_s", "degrade"},
}
# where the lidar odometry's frame is laid in the world: on the ground truth's pose at its first frame inside it, as
# given (already in the world frame), or on the filter's initial pose at its start
ANCHORS = ("groundtruth", "none", "start")
TOP_KEYS = {"name", "description", "attribution", "geodetic_origin", "streams", "config", "truth", "platform"}
# what carried the sensors: 'car' / 'wheeled' turn the non-holonomic constraint on by default (filter.nhc: auto)
PLATFORMS = ("car", "wheeled", "aerial", "handheld", "legged", "other")


BAG_SUFFIXES = (".bag", ".db3", ".mcap")


def manifest_file(path: str | Path) -> Path | None:
    """The manifest a dataset path names: the file itself (not a bag), or the folder's ``dataset.yaml``; None for a
    folder without one (a KITTI raw drive, an ASL folder, a bag folder)."""
    path = Path(path)
    if path.is_file():
        return None if path.suffix in BAG_SUFFIXES else path
    return path / "dataset.yaml" if (path / "dataset.yaml").is_file() else None


def declares_ground_truth(path: str | Path) -> bool:
    """Whether the dataset at ``path`` has a groundtruth stream, from its manifest alone (no stream read): a sweep
    ranks drives without one by their innovations before it runs them. Anything but a readable manifest (a KITTI raw
    folder, an ASL folder: both carry their truth) counts as having one."""
    m = manifest_file(path)
    if m is None:
        return True
    try:
        body = yaml.safe_load(m.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return True                    # (the run says what is wrong with it)
    streams = body.get("streams") if isinstance(body, dict) else None
    return not isinstance(streams, dict) or "groundtruth" in streams


def load_dataset(path: str | Path, extra_streams: tuple[StreamSpec, ...] | None = None) -> Dataset:
    """Load a dataset from a manifest file, a folder holding ``dataset.yaml``, or a KITTI raw drive folder.

    ``extra_streams``: streams beyond the built-in ones that the manifest may name; None = those the
    registered observations declare (the registry is where a new stream is declared, with its observation).
    """
    if extra_streams is None:
        from ..filters.observations import extra_streams as registered

        extra_streams = registered()
    path = Path(path)
    extra = {s.name: s for s in extra_streams}
    if not path.exists():
        raise DataFormatError(path, None, "dataset not found (expected a folder with dataset.yaml, a dataset.yaml, a KITTI raw "
                                          "drive folder or a EuRoC / TUM-VI folder)")
    manifest = manifest_file(path)
    if manifest is not None:
        return _from_manifest(manifest, extra)
    if path.suffix in BAG_SUFFIXES or (path / "metadata.yaml").is_file():
        raise DataFormatError(path, None, _a_bag_is_not_a_dataset(path))
    from . import euroc

    asl = euroc.implicit_streams(path)
    if asl is not None:
        # an ASL folder has no aiding sensor of its own: without a manifest naming one, the run is dead reckoning
        log.warning("%s: a EuRoC / TUM-VI folder without a manifest: IMU and ground truth only, so the fused estimate is "
                    "dead reckoning; name a pose or position stream in a dataset.yaml to fuse it", path)
        body = {"name": path.name, "streams": asl, "config": {"filter": {"lidar_update": "none", "use_gnss": False}}}
        return _from_manifest_dict(body, path, path / "(implicit EuRoC manifest)", extra)
    if (path / "oxts").is_dir():
        streams = {s: {"format": "kitti_oxts", "path": "oxts"} for s in ("imu", "gnss", "groundtruth")}
        # the OXTS rates lag the packet clock: estimated, or the device figure (fusion_eval.timing)
        streams["imu"]["gyro_lag_s"] = "auto"
        streams.update({n: {"format": "kitti_oxts", "path": "oxts"} for n, spec in extra.items() if spec.implicit_kitti_raw})
        # a raw drive has no lidar odometry: like a EuRoC folder's, its implicit manifest suggests the filter without
        # it (a configuration or --set that asks for lidar updates still overrides it, and is refused)
        body = {"name": path.name, "streams": streams, "config": {"filter": {"lidar_update": "none"}},
                "platform": "car"}                # KITTI's recording platform, a VW Passat
        return _from_manifest_dict(body, path, path / "(implicit manifest)", extra)
    raise DataFormatError(path, None, "expected dataset.yaml, an oxts/ folder (KITTI raw drive) or mav0/imu0/data.csv "
                                      "(EuRoC / TUM-VI) in this folder")


def _a_bag_is_not_a_dataset(path: Path) -> str:
    """What to write for a bag given where a dataset is due: which topic is which stream is the user's to say."""
    from . import rosbag

    try:
        listed = "; its topics: " + ", ".join(f"{name} [{typ}]" for name, (typ, _) in sorted(rosbag.topics(path).items()))
    except FusionEvalError as exc:
        listed = f" (and it does not read as one: {exc})"
    return ("a ROS bag, not a dataset: write a dataset.yaml whose streams name its topics ({format: rosbag, path: "
            f"{path.name}, topic: ...}}; README 'Your own data') and run that, or score its pose topics with fusion-eval "
            f"evaluate --bag{listed}")


def _from_manifest(manifest: Path, extra: dict) -> Dataset:
    from ._text import read_text

    try:
        body = yaml_lines.load(read_text(manifest, "a YAML dataset manifest"))     # mappings that know their lines
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise DataFormatError(manifest, None if mark is None else mark.line + 1, f"not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(body, dict):
        hint = ""
        if isinstance(body, (str, int, float)) or manifest.suffix not in (".yaml", ".yml"):
            hint = (" (this looks like a data file: give the dataset folder, its dataset.yaml, a KITTI raw drive folder or "
                    "a EuRoC folder; to evaluate a trajectory file use fusion-eval evaluate)")
        raise DataFormatError(manifest, None, f"a manifest must be a YAML mapping with 'streams'{hint}")
    return _from_manifest_dict(body, manifest.parent, manifest, extra)


def _in_radians(fix) -> bool:
    """A first fix hundreds of km from the origin whose both angles lie within pi: radians read as degrees."""
    return abs(fix[0]) <= np.pi and abs(fix[1]) <= np.pi


def _from_manifest_dict(body: dict, root: Path, manifest: Path, extra: dict | None = None) -> Dataset:
    extra = extra or {}
    unknown = set(body) - TOP_KEYS
    if unknown:
        raise ConfigError(f"{at(manifest, body, sorted(unknown)[0])}: unknown manifest key {sorted(unknown)[0]!r} (known: {', '.join(sorted(TOP_KEYS))})")
    streams = body.get("streams")
    if not isinstance(streams, dict) or "imu" not in streams:
        raise ConfigError(f"{at(manifest, body, 'streams')}: 'streams' must be a mapping that names at least 'imu'")
    for name, spec in streams.items():
        if name not in STREAMS and name not in extra:
            raise ConfigError(f"{at(manifest, streams, name)}: unknown stream {name!r} (known: {', '.join([*STREAMS, *extra])})")
        if not isinstance(spec, dict):
            raise ConfigError(f"{at(manifest, streams, name)}: stream {name!r} must be a mapping with 'format' and 'path'")
        registered = for_stream(name) if name in STREAMS else {}
        allowed = STREAM_KEYS[name] if name in STREAMS else extra[name].keys
        formats = tuple(registered) if name in STREAMS else tuple(extra[name].readers)
        if not isinstance(spec.get("format"), str):
            # a list or a mapping here ended in a traceback (unhashable type; a corrupted-input review)
            raise ConfigError(f"{at(manifest, spec, 'format')}: stream {name!r} needs a 'format', one word (known for "
                              f"{name}: {', '.join(formats)}), got {spec.get('format')!r}")
        if spec.get("format") in registered:
            allowed = allowed | registered[spec["format"]].keys_for(name)
        fmt = spec.get("format")
        if fmt not in formats:
            raise ConfigError(f"{at(manifest, spec, 'format')}: stream {name!r} has unknown format {fmt!r} (known for {name}: {', '.join(formats)})")
        bad = {k for k in set(spec) - allowed if not (name in ("groundtruth", "lidar") and k.startswith("T_imu_"))}
        if bad:
            raise ConfigError(f"{at(manifest, spec, sorted(bad)[0])}: unknown key {sorted(bad)[0]!r} in stream {name!r} "
                              f"(known: {', '.join(sorted(allowed))})")
        extr = [k for k in spec if k.startswith("T_imu_")]
        if extr and extr != [f"T_imu_{spec.get('frame', 'imu')}"]:
            # an extrinsic for another frame than the stream's would be ignored, and the poses taken as the IMU's
            raise ConfigError(f"{at(manifest, spec, extr[0])}: stream {name!r} gives {extr[0]} but its frame is {spec.get('frame', 'imu')!r}: "
                              f"set frame: {extr[0][6:]} (the poses are of that sensor)")
        if not isinstance(spec.get("path"), str) or not spec["path"]:
            raise ConfigError(f"{at(manifest, spec, 'path')}: stream {name!r} needs a 'path' (a file or folder name)")
        if not (root / spec["path"]).exists():
            # named with the manifest's line: a reader's 'expected a KITTI raw drive folder' read as if the folder
            # held the wrong files (a shipped manifest's ../shared paths, run from an installed copy)
            raise ConfigError(f"{at(manifest, spec, 'path')}: stream {name!r}: path {spec['path']!r} does not exist "
                              f"(looked for {root / spec['path']})")
        if fmt != "kitti_poses" and "times" in spec:
            raise ConfigError(f"{at(manifest, spec, 'times')}: 'times' applies to kitti_poses streams only (stream {name!r} is {fmt}: "
                              "its file has its own timestamps)")
        for key in ("time_offset_s", "gyro_lag_s", "accel_lag_s"):
            v = spec.get(key, 0.0)
            may_be_auto = key != "time_offset_s" or name == "lidar"     # estimated by fusion_eval.timing
            if not (v == "auto" and may_be_auto) and not _is_num(v):
                raise ConfigError(f"{at(manifest, spec, key)}: {key} of stream {name!r} must be a number of seconds, got {v!r}")
            if key != "time_offset_s" and _is_num(v) and abs(v) > plausible.MAX_LAG_S:
                raise ConfigError(f"{at(manifest, spec, key)}: {key} of stream {name!r} is {v:g} s: {plausible.LAG_NOTE}")
            if key == "time_offset_s" and _is_num(v) and not abs(v) <= plausible.MAX_STAMP_S:
                # 1e300 was reported as a duplicate stamp of the data file, with two 300-digit numbers (a review)
                raise ConfigError(f"{at(manifest, spec, key)}: time_offset_s of stream {name!r} is {v:g} s: beyond any "
                                  f"clock's (|offset| <= {plausible.MAX_STAMP_S:g} s; a boot clock against POSIX time is "
                                  "about 1.7e9 s)")
        if "degrade" in spec and not isinstance(spec["degrade"], bool):
            raise ConfigError(f"{at(manifest, spec, 'degrade')}: 'degrade' of stream {name!r} must be true or false, got {spec['degrade']!r}")

    oxts_cache: dict[Path, kitti_oxts.OxtsPackets] = {}

    def oxts(spec) -> kitti_oxts.OxtsPackets:
        p = (root / spec["path"]).resolve()
        if p not in oxts_cache:
            oxts_cache[p] = kitti_oxts.read_oxts(p)
        return oxts_cache[p]

    imu_spec = streams["imu"]
    imu_pk = oxts(imu_spec) if imu_spec["format"] == "kitti_oxts" else None      # a KITTI pose file's clock

    def ctx_with(origin_lla) -> ReadContext:
        return ReadContext(root=root, manifest=manifest, origin=origin_lla, oxts=oxts, imu_packets=imu_pk)

    def read(name: str, origin_lla):
        """Stream ``name`` through its format's reader, and what the reader noted."""
        ctx = ctx_with(origin_lla)
        return for_stream(name)[streams[name]["format"]].readers[name](streams[name], ctx), ctx.notes

    imu, _ = read("imu", None)

    @lru_cache(maxsize=None)          # each read once: the origin and the receiver's check both ask
    def oxts_fix():
        geo_src = next((streams[s] for s in ("gnss", "groundtruth", "imu") if s in streams and streams[s]["format"] == "kitti_oxts"), None)
        return kitti_oxts.first_valid_fix(oxts(geo_src)) if geo_src else None

    @lru_cache(maxsize=None)
    def gnss_fix():
        g = streams.get("gnss")
        ff = for_stream("gnss")[g["format"]].first_fix if g is not None else None
        return ff(g, ctx_with(None)) if ff else None

    def first_fix():
        fix = oxts_fix()
        return gnss_fix() if fix is None else fix

    origin = body.get("geodetic_origin", "first_fix")
    if origin == "first_fix":
        origin_t = first_fix()
    elif isinstance(origin, (list, tuple)) and len(origin) == 3 and all(_is_num(v) for v in origin):
        origin_t = tuple(float(v) for v in origin)
        fix = first_fix() if abs(origin_t[0]) <= 90.0 else None
        far = None if fix is None else great_circle_m(origin_t[:2], fix[:2])
        if far is not None and far > MAX_ORIGIN_DISTANCE_M:
            raise ConfigError(f"{at(manifest, body, 'geodetic_origin')}: geodetic_origin {list(origin)} is {far / 1e3:,.0f} km "
                              f"from the drive's first fix ({fix[0]:.6f}, {fix[1]:.6f}); an origin is where the local "
                              f"frame is, within {MAX_ORIGIN_DISTANCE_M / 1e3:g} km of the data ("
                              + ("the fixes in radians?" if _in_radians(fix) else
                                 "latitude and longitude swapped, in the origin or in the fixes? both go lat, lon, alt")
                              + ")")
    else:
        raise ConfigError(f"{at(manifest, body, 'geodetic_origin')}: geodetic_origin must be 'first_fix' or [lat_deg, lon_deg, alt_m], got {origin!r}")
    if origin_t is not None:
        from ..geo import check_geodetic

        try:
            check_geodetic(*origin_t, str(manifest), what="geodetic_origin")
        except DataFormatError as exc:
            raise ConfigError(f"{at(manifest, body, 'geodetic_origin')}: {exc.expected}") from None
        # a receiver's fixes beside the OXTS packets that set the origin: checked against it too (a CSV's lat and lon
        # swapped or in radians ran, the filter diverging blaming the lidar, where a CSV truth's were refused; a review)
        g = streams.get("gnss")
        fix = gnss_fix() if g is not None and g["format"] != "kitti_oxts" and oxts_fix() is not None else None
        far = None if fix is None else great_circle_m(origin_t[:2], fix[:2])
        if far is not None and far > MAX_ORIGIN_DISTANCE_M:
            raise DataFormatError(ctx_with(None).path(g), None,
                                  f"expected fixes near the drive; its first valid fix ({fix[0]:.6f}, {fix[1]:.6f}) is {far / 1e3:,.0f} "
                                  f"km from the local frame's origin ({origin_t[0]:.6f}, {origin_t[1]:.6f}, from "
                                  f"{'the OXTS packets' if origin == 'first_fix' else 'geodetic_origin'}): "
                                  + ("in radians?" if _in_radians(fix) else
                                     "latitude and longitude swapped? both go lat, lon, alt"))

    ctx = ctx_with(origin_t)
    got = {name: read(name, origin_t) for name in ("odometer", "gnss", "groundtruth", "lidar") if name in streams}
    odo, gnss = (got[n][0] if n in got else None for n in ("odometer", "gnss"))
    gt, lidar = (_in_imu_frame(got[n][0], streams[n], root, manifest) if n in got else None for n in ("groundtruth", "lidar"))
    # orientations as the file holds them (the sensor's frame): a misread quaternion order is told from them alone
    misread = [w for n in ("groundtruth", "lidar") if n in got
               for w in [plausible.pose_reading(n, got[n][0], for_stream(n)[streams[n]["format"]].quaternion)] if w]
    misread += [w for n in ("groundtruth", "lidar") if n in got for w in [_unrectified_cam0(streams[n], root)] if w]
    lidar_notes = got["lidar"][1] if "lidar" in got else {}
    extra_series = {name: extra[name].readers[streams[name]["format"]](streams[name], ctx)
                    for name in streams if name in extra}
    plausible.check_dataset(imu, {"groundtruth": gt, "gnss": gnss, "lidar": lidar, "odometer": odo, **extra_series})

    description: dict[str, Any] = {
        "manifest": str(manifest),
        "attribution": body.get("attribution"),
        "description": body.get("description"),
        "time_offset_s": {s: (v if v == "auto" else float(v)) for s in streams
                          for v in [streams[s].get("time_offset_s", 0.0)]},
        "gyro_lag_s": imu_spec.get("gyro_lag_s", 0.0),
        "accel_lag_s": imu_spec.get("accel_lag_s", 0.0),
        # a drive without ground truth anchors its lidar on the filter's start (the only pose it has)
        "lidar_anchor": streams.get("lidar", {}).get("anchor", "groundtruth" if "groundtruth" in streams else "start"),
        "misread_poses": misread,            # said with the preparation's data warnings
        "geodetic_origin_from": ("the first valid fix" if origin == "first_fix" else "the manifest's geodetic_origin"),
        # the local frame's origin is a receiver's first fix, and the ground truth is not of the same OXTS solution:
        # that fix's error is then an offset of every fix from the truth (plausible.gnss_offset)
        "origin_from_first_fix": origin == "first_fix" and origin_t is not None
                                 and all(streams.get(k, {}).get("format") != "kitti_oxts" for k in ("gnss", "groundtruth")),
        # the lidar frame clock recovered from the stamps of the IMU packets (times.smooth_s), if asked for
        "lidar_clock": lidar_notes.get("clock"),
        # a times file put on the IMU packets' clock (times.align_to: imu): the median shift it took
        "lidar_times_aligned": lidar_notes.get("times_aligned"),
        # KITTI's OXTS position is the GPS/INS solution (= the ground truth): degrade it by default;
        # a receiver's (or a simulator's) fixes are used as they are.
        "gnss_degrade": bool(streams.get("gnss", {}).get("degrade", streams.get("gnss", {}).get("format") == "kitti_oxts")),
        # KITTI's OXTS forward speed is the GPS/INS solution too: add noise unless told otherwise
        "odometer_degrade": bool(streams.get("odometer", {}).get("degrade", streams.get("odometer", {}).get("format") == "kitti_oxts")),
        # a declared stream is degraded when its format is a GPS/INS solution, unless the entry says otherwise
        "degrade": {n: bool(streams[n].get("degrade", streams[n]["format"] in extra[n].degrade_formats))
                    for n in streams if n in extra},
        "config": body.get("config") or {},
        "truth": body.get("truth"),
        "platform": body.get("platform"),
        "streams": {s: {k: (str(v) if k == "path" else v) for k, v in streams[s].items()} for s in streams},
    }
    if description["platform"] is not None and description["platform"] not in PLATFORMS:
        raise ConfigError(f"{at(manifest, body, 'platform')}: 'platform' must be one of {', '.join(PLATFORMS)}, got {description['platform']!r}")
    if not isinstance(description["config"], dict):
        raise ConfigError(f"{at(manifest, body, 'config')}: 'config' must be a mapping of configuration sections (suggested settings)")
    if description["lidar_anchor"] not in ANCHORS:
        raise ConfigError(f"{at(manifest, streams.get('lidar'), 'anchor')}: lidar 'anchor' must be one of "
                          f"{', '.join(ANCHORS)}, got {description['lidar_anchor']!r}")
    if description["lidar_anchor"] == "groundtruth" and "lidar" in streams and "groundtruth" not in streams:
        raise ConfigError(f"{at(manifest, streams.get('lidar'), 'anchor')}: lidar 'anchor: groundtruth', but the "
                          "manifest has no groundtruth stream; use anchor: start (the filter's initial pose)")
    return Dataset(name=str(body.get("name", root.name)), imu=imu, groundtruth=gt, gnss=gnss, lidar=lidar, odometer=odo,
                   geodetic_origin=origin_t, description=description, extra=extra_series)


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _transform(spec_value, root: Path, where: str, what: str) -> np.ndarray:
    """A 4x4 transform from a manifest value; ``where``: its place (``file:line``), for messages."""
    if isinstance(spec_value, dict) and isinstance(spec_value.get("file"), str):
        unknown = sorted(set(map(str, spec_value)) - {"file", "key"})
        if unknown:               # a misspelt 'key' (or an 'invert' it does not have) was ignored
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} in {what} (known: file, key)")
        if spec_value.get("key") is not None and not isinstance(spec_value["key"], str):
            raise ConfigError(f"{where}: {what}: 'key' must be the name of a calibration entry (such as Tr), got "
                              f"{spec_value['key']!r}")
        return kitti_poses.calib_transform(root / spec_value["file"], spec_value.get("key"))
    if isinstance(spec_value, (list, tuple)) and len(spec_value) in (12, 16) and all(_is_num(v) for v in spec_value):
        T = np.eye(4)
        T[: len(spec_value) // 4, :] = np.asarray(spec_value, float).reshape(-1, 4)
        if len(spec_value) == 16 and np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
            # a column-major matrix (Eigen's or numpy's .T written out) has its 3x3 block transposed, which is still
            # a rotation: only the last row tells, and it went on to a traceback
            raise ConfigError(f"{where}: {what}: the last row of a 4x4 must be 0 0 0 1, got "
                              f"{' '.join(f'{v:g}' for v in T[3])} (16 numbers are read row by row: a column-major "
                              "matrix written out? give the 12 numbers of the 3x4 [R | t] row by row)")
        R = T[:3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
            raise ConfigError(f"{where}: {what}: the 3x3 block must be a rotation (R^T R = I, det +1)")
        try:
            kitti_poses.check_lever_arm(T, where, what)
        except DataFormatError as exc:
            raise ConfigError(str(exc)) from None
        return T
    raise ConfigError(f"{where}: {what} must be {{file: ..., key: ...}} or a list of 12 numbers (3x4 row-major; 16 "
                      "for the whole 4x4)")


def _unrectified_cam0(spec: dict, root: Path) -> str:
    """KITTI raw's ``calib_velo_to_cam.txt`` (entries R, T and the camera's delta_f) given as ``T_cam0_velo``: it maps
    into the *unrectified* cam0, while KITTI's odometry poses (its ground truth, and every odometry run on its
    sequences) are in the rectified one, ``R_rect_00`` (calib_cam_to_cam.txt) away, 12.7 mrad on 2011_09_30: read as
    the rectified frame, SiMpLE 07's lidar went 0.568 -> 1.599 m and the fusion 0.417 -> 0.595 m with no word (a review
    against the shared data's README). A warning; '' otherwise."""
    v = spec.get("T_cam0_velo") if spec.get("frame") == "cam0" else None
    if not (isinstance(v, dict) and isinstance(v.get("file"), str) and v.get("key") is None):
        return ""
    try:
        entries = kitti_poses.read_kitti_calib(root / v["file"])
    except (OSError, ValueError, FusionEvalError):
        return ""
    if "delta_f" not in entries and "velo_to_cam" not in Path(v["file"]).name:
        return ""
    return (f"T_cam0_velo is read from {v['file']}, KITTI raw's velodyne-to-camera calibration, which maps into the "
            "unrectified cam0; KITTI odometry poses (and odometries run on its sequences) are in the rectified cam0, "
            "R_rect_00 of calib_cam_to_cam.txt away (12.7 mrad on 2011_09_30): give the odometry sequence's calib.txt "
            "{file: calib.txt, key: Tr} instead, or R_rect_00 times this transform as 12 numbers")


def _extrinsic(spec, root, manifest) -> np.ndarray:
    """``T_frame_imu`` (maps IMU coordinates into the pose stream's sensor frame), from ``T_imu_<frame>`` (the
    sensor frame's pose in the IMU frame: 12 numbers, ``{file, key}`` or ``{tf_static: [imu_frame, frame]}`` read
    from the stream's bag), or for ``cam0`` from KITTI's ``T_cam0_imu`` or ``T_cam0_velo`` and ``T_velo_imu``."""
    frame = spec.get("frame", "imu")
    if not isinstance(frame, str) or not frame:
        raise ConfigError(f"{at(manifest, spec, 'frame')}: pose 'frame' must be a frame name ('imu', 'cam0' or one with T_imu_<frame>)")
    if frame == "imu":
        return np.eye(4)
    key = f"T_imu_{frame}"
    if key in spec:
        v = spec[key]
        if isinstance(v, dict) and "tf_static" in v:
            unknown = sorted(set(map(str, v)) - {"tf_static", "bag"})
            if unknown:           # an 'invert: true' was ignored: the transform taken the way it was written
                raise ConfigError(f"{at(manifest, spec, key)}: unknown key {unknown[0]!r} in {key} (known: tf_static, "
                                  "bag; to invert, swap the two frames)")
            pair = v["tf_static"]
            if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(x, str) for x in pair)):
                raise ConfigError(f"{at(manifest, spec, key)}: {key}: tf_static must be [imu_frame, {frame}_frame]")
            from . import rosbag

            bag = root / v.get("bag", spec["path"])
            try:
                T = rosbag.static_transform(bag, pair[0], pair[1])
            except DataFormatError as exc:   # the bag's own message, placed at the manifest key that named it
                raise ConfigError(f"{at(manifest, spec, key)}: {key}: {exc}") from None
            if T is None:
                have = ", ".join(f"{a}->{b}" for a, b in rosbag.static_edges(bag)) or "none"
                raise ConfigError(f"{at(manifest, spec, key)}: {key}: no /tf_static transform {pair[0]} -> {pair[1]} in "
                                  f"{bag}, directly or through other frames (its static edges: {have})")
        else:
            T = _transform(v, root, at(manifest, spec, key), key)
        return np.linalg.inv(T)
    if frame == "cam0":
        if "T_cam0_imu" in spec:
            return _transform(spec["T_cam0_imu"], root, at(manifest, spec, "T_cam0_imu"), "T_cam0_imu")
        if "T_cam0_velo" in spec and "T_velo_imu" in spec:
            return (_transform(spec["T_cam0_velo"], root, at(manifest, spec, "T_cam0_velo"), "T_cam0_velo")
                    @ _transform(spec["T_velo_imu"], root, at(manifest, spec, "T_velo_imu"), "T_velo_imu"))
        raise ConfigError(f"{at(manifest, spec, 'frame')}: frame 'cam0' needs T_imu_cam0, T_cam0_imu, or T_cam0_velo and T_velo_imu")
    raise ConfigError(f"{at(manifest, spec, 'frame')}: frame {frame!r} needs {key} (the {frame} frame's pose in the IMU frame: 12 numbers "
                      f"(3x4 row-major), {{file: ..., key: ...}} or {{tf_static: [imu_frame, {frame}_frame]}})")


def _in_imu_frame(poses: PoseSeries, spec: dict, root: Path, manifest: Path) -> PoseSeries:
    """A pose stream's poses of its sensor frame ``c`` as poses of the IMU: ``T_x_bi = T_x_ci T_c_b``, where x is the
    stream's reference frame (the world when anchor is 'none'; the sensor's first frame otherwise, and anchoring
    removes that constant)."""
    T_c_b = _extrinsic(spec, root, manifest)
    if np.allclose(T_c_b, np.eye(4)):
        return poses
    T_b = make_T(poses.R_wb(), poses.p_w_m) @ T_c_b[None]
    v_w = None
    if poses.v_w_mps is not None:
        # the IMU point's velocity: the sensor's plus the lever arm's turn, d/dt (R_wc t_cb) (was dropped: the
        # filter then started from the positions and the report said the stream had no velocity)
        arm_w = np.einsum("nij,j->ni", poses.R_wb(), T_c_b[:3, 3])
        turn = np.gradient(arm_w, poses.t_s, axis=0) if len(poses) > 1 and np.all(np.diff(poses.t_s) > 0) else 0.0
        v_w = poses.v_w_mps + turn
    return PoseSeries(t_s=poses.t_s, p_w_m=T_b[:, :3, 3], q_wb_xyzw=matrix_to_quat_xyzw(T_b[:, :3, :3]), v_w_mps=v_w,
                      source=poses.source, lines=poses.lines)
