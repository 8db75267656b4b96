"""GNSS velocity: its stream from KITTI OXTS packets and from files, its degradation, and what it does."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fusion_eval.geo import enu_rotation
import pytest
from click.testing import CliRunner

from conftest import KITTI00
from fusion_eval.cli import main
from fusion_eval.config import load_config
from fusion_eval.datasets import kitti_oxts
from fusion_eval.errors import ConfigError, DataFormatError
from fusion_eval.prepare import prepare
from fusion_eval.session import dataset
from fusion_eval.so3 import euler_rpy_to_matrix


def test_kitti_stream_is_ve_vn_and_vu_rotated_with_the_reported_accuracy():
    ds = dataset(KITTI00)
    vs = ds.extra["gnss_velocity"]
    pk = kitti_oxts.read_oxts(KITTI00 / "oxts")
    v = pk.values
    R = euler_rpy_to_matrix(v[:, kitti_oxts.ROLL], v[:, kitti_oxts.PITCH], v[:, kitti_oxts.YAW])
    up = (R @ v[:, kitti_oxts.VF:kitti_oxts.VU + 1, None])[:, 2, 0]
    # in the local level frame of each packet, turned into the origin's ENU frame (the positions' own)
    local = np.column_stack([v[:, kitti_oxts.VE], v[:, kitti_oxts.VN], up])
    turn = enu_rotation(v[:, kitti_oxts.LAT], v[:, kitti_oxts.LON], *ds.geodetic_origin[:2])
    assert np.allclose(vs.values, np.einsum("nij,nj->ni", turn, local), atol=1e-12)
    assert 1e-4 < np.abs(vs.values - local).max() < 0.05       # kitti-00: its frames differ by up to 0.11 mrad (measured), x up to 14 m/s
    real = ~pk.filled
    assert np.array_equal(vs.std[real, 0], v[real, kitti_oxts.VEL_ACC]) and np.array_equal(vs.filled, pk.filled)


def test_kitti_vertical_rate_follows_the_altitude():
    """The vertical rate (vu rotated into the world) against the differenced OXTS altitude: the same sign and
    scale (a frame or sign error shows as a negative correlation), and the -0.068 m/s bias the README reports."""
    vs = dataset(KITTI00).extra["gnss_velocity"]
    pk = kitti_oxts.read_oxts(KITTI00 / "oxts")
    ok = ~pk.filled
    t, up = pk.t_s[ok], vs.values[ok, 2]
    dalt = np.gradient(pk.values[ok, kitti_oxts.ALT], t)
    assert np.corrcoef(up, dalt)[0, 1] > 0.5          # measured 0.60: the vertical motion is small (0.09 m/s RMS)
    assert 0.5 < np.polyfit(dalt, up, 1)[0] < 1.5     # measured 0.70
    assert abs(np.mean(up - dalt) + 0.068) < 0.005


def test_degraded_like_the_gnss_position_at_the_same_epochs_with_independent_noise():
    ds = dataset(KITTI00)
    cfg = load_config(None, ("filter.use_gnss_velocity=true", "gnss.outages_s=[[100, 150]]"))
    prep = prepare(ds, cfg)
    vs, g = prep.streams["gnss_velocity"], prep.gnss
    assert np.array_equal(vs.t_s, g.t_s)                          # the receiver's epochs: same rate, same outages
    info = prep.applied["gnss_velocity"]
    assert info["degraded"] and info["rate_hz"] == 1.0 and info["outages_s"] == [[100.0, 150.0]]
    raw = ds.extra["gnss_velocity"]
    i = np.searchsorted(raw.t_s, vs.t_s)
    noise = vs.values - raw.values[i]
    assert np.allclose(noise.std(axis=0), [0.05, 0.05, 0.1], rtol=0.15)
    # the position noise is what it was without the velocity (drawn from its own generator)
    prep0 = prepare(ds, load_config(None, ("gnss.outages_s=[[100, 150]]",)))
    assert np.array_equal(prep0.gnss.p_w_m, g.p_w_m)
    assert abs(np.corrcoef(noise[:, 0], (g.p_w_m - ds.gnss.p_w_m[np.searchsorted(ds.gnss.t_s, g.t_s)])[:, 0])[0, 1]) < 0.15


def test_vector_txt_stream_with_and_without_std_columns(tmp_path):
    from conftest import make_slice

    d = make_slice(tmp_path / "ds", 200)
    t0 = float(dataset(d).imu.t_s[20])
    (d / "vel.txt").write_text("t_s,ve,vn,vu\n" + "".join(f"{t0 + k:.3f},1.0,2.0,0.0\n" for k in range(10)))
    m = d / "dataset.yaml"
    text = m.read_text().replace("  gnss_velocity:                     # OXTS ve, vn and vu rotated (GPS/INS solution: degraded like the GNSS)\n    format: kitti_oxts\n    path: oxts\n",
                                 "  gnss_velocity:\n    format: vector_txt\n    path: vel.txt\n    std_mps: [0.1, 0.1, 0.3]\n")
    assert "vel.txt" in text
    m.write_text(text)
    vs = dataset(d).extra["gnss_velocity"]
    assert vs.values.shape == (10, 3) and np.allclose(vs.std[0], [0.1, 0.1, 0.3])
    cfg = load_config(None, ("filter.use_gnss_velocity=true",))
    prep = prepare(dataset(d), cfg)
    assert prep.applied["gnss_velocity"]["degraded"] is False and len(prep.streams["gnss_velocity"]) == 10
    m.write_text(text.replace("    std_mps: [0.1, 0.1, 0.3]\n", ""))
    with pytest.raises(DataFormatError, match="no std columns"):
        dataset(d)
    (d / "vel.txt").write_text("1 2 3 4 5 6 7\n2 2 3 x 5 6 7\n")
    with pytest.raises(DataFormatError, match=r"vel.txt:2: .*expected a number, got 'x'"):
        dataset(d)


def test_a_dataset_without_the_stream_says_which_key_needs_it(tmp_path):
    from conftest import make_slice

    d = make_slice(tmp_path / "ds", 120)
    m = d / "dataset.yaml"
    m.write_text(m.read_text().replace("  gnss_velocity:                     # OXTS ve, vn and vu rotated (GPS/INS solution: degraded like the GNSS)\n    format: kitti_oxts\n    path: oxts\n", ""))
    with pytest.raises(ConfigError, match="has no gnss_velocity stream, which filter.use_gnss_velocity needs"):
        prepare(dataset(d), load_config(None, ("filter.use_gnss_velocity=true",)))


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("gv") / "urban"
    r = CliRunner().invoke(main, ["-q", "simulate", str(d), "--profile", "urban", "--duration", "120", "--set", "imu.rate_hz=50",
                                  "--set", "output.layout=csv"])
    assert r.exit_code == 0, r.output
    return d


def _run(d: Path, tmp: Path, *sets: str) -> dict:
    out = tmp / f"run{len(list(tmp.iterdir()))}"
    args = ["-q", "run", str(d), "--out", str(out), "--no-plots"]
    for s in sets:
        args += ["--set", s]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    return json.loads((out / "metrics.json").read_text())


@pytest.mark.slow
def test_simulated_receiver_velocity_improves_the_fusion_and_is_consistent(sim, tmp_path):
    manifest = (sim / "dataset.yaml").read_text()
    assert "gnss/velocity.txt" in manifest
    off = _run(sim, tmp_path)
    on = _run(sim, tmp_path, "filter.use_gnss_velocity=true")
    e_off, e_on = (m["estimates"]["fused"]["ape"] for m in (off, on))
    assert e_on["translation_m"]["rmse"] < 0.9 * e_off["translation_m"]["rmse"], (e_off, e_on)
    assert e_on["rotation_deg"]["rmse"] < e_off["rotation_deg"]["rmse"]
    nis = on["nis"]["gnss_velocity"]
    assert nis["dof"] == 3 and 2.4 < nis["mean"] < 3.6 and nis["fraction_in_95"] > 0.9, nis
    horiz = _run(sim, tmp_path, "filter.use_gnss_velocity=true", "gnss_velocity.components=en")
    assert horiz["nis"]["gnss_velocity"]["dof"] == 2


def test_an_outage_of_a_receivers_fixes_removes_its_velocities_too(sim, tmp_path):
    """On a receiver's stream (not marked for degradation) gnss.outages_s removed the positions and left every velocity
    fused, and gnss_velocity.seed/rate_hz/noise_std_mps did nothing with no word (a configuration audit)."""
    whole = _run(sim, tmp_path, "filter.use_gnss_velocity=true")
    cut = _run(sim, tmp_path, "filter.use_gnss_velocity=true", "gnss.outages_s=[[20, 60]]", "gnss_velocity.seed=4")
    gv = cut["preprocessing"]["gnss_velocity"]
    assert gv["fixes_in_outages"] == 40 and gv["fixes_used"] == whole["preprocessing"]["gnss_velocity"]["fixes_used"] - 40
    assert cut["nis"]["gnss_velocity"]["epochs"] == gv["fixes_used"]
    assert any("gnss_velocity.seed=4 applies only to a velocity stream marked for degradation" in w
               for w in cut["preprocessing"]["data_warnings"])
