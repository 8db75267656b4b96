"""Configuration: defaults, YAML, --set, validation, and the one conversion to SI."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from fusion_eval.config import Settings, default_config, load_config, schema
from fusion_eval.errors import ConfigError


def test_configs_default_yaml_spells_out_the_builtin_defaults():
    assert load_config(ROOT / "configs" / "default.yaml") == default_config()


def test_lidar_imu_config_turns_gnss_off():
    cfg = load_config(ROOT / "configs" / "lidar-imu.yaml")
    assert cfg["filter"]["use_gnss"] is False and cfg["filter"]["lidar_update"] == "relative"


def test_set_overrides_yaml_and_parses_values(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("imu:\n  gyro_noise_dps_sqrthz: 0.5\n")
    cfg = load_config(p, ("imu.gyro_noise_dps_sqrthz=0.25", "gnss.noise_std_m=3", "gnss.rate_hz=null"))
    assert cfg["imu"]["gyro_noise_dps_sqrthz"] == 0.25
    assert cfg["gnss"]["noise_std_m"] == [3.0, 3.0, 3.0]
    assert cfg["gnss"]["rate_hz"] is None


@pytest.mark.parametrize("item,msg", [
    ("imu.nope=1", "unknown key"),
    ("nosection.x=1", "unknown section"),
    ("imu.gyro_noise_dps_sqrthz=-1", ">= 0"),
    ("gnss.noise_std_m=[1,2]", "3 numbers"),
    ("gnss.outages_s=[[5, 1]]", "end > start"),
    ("filter.use_gnss=maybe", "true or false"),
    ("novalue", "section.key=value"),
    # an empty value was null: an empty shell variable kept every GNSS fix (found by a corrupted-input review)
    ("gnss.rate_hz=", r"no value \(write gnss.rate_hz=null for null\)"),
    ("gnss.rate_hz=  ", "no value"),
    ("imu.gap_factor=0.5", "must be > 1"),      # every IMU step a gap, 10x the process noise, no word
])
def test_invalid_settings_are_rejected_with_the_key(item, msg):
    with pytest.raises(ConfigError, match=msg):
        load_config(None, (item,))


def test_human_units_convert_to_si_once():
    cfg = load_config(None, ("imu.gyro_noise_dps_sqrthz=1.0", "init.yaw_std_deg=2.0", "lidar.relative_att_std_deg=0.5"))
    s = Settings(cfg)
    assert np.isclose(s.imu.gyro_noise_rps_sqrthz, np.pi / 180)
    assert np.isclose(s.init.yaw_std_rad, 2 * np.pi / 180) and np.isclose(s.init.roll_pitch_std_rad, 0.1 * np.pi / 180)
    assert np.isclose(s.lidar.relative_att_std_rad, 0.5 * np.pi / 180)
    assert s.imu.accel_noise_mps2_sqrthz == cfg["imu"]["accel_noise_mps2_sqrthz"]      # SI already: unchanged
    with pytest.raises(AttributeError, match="no such"):
        s.imu.gyro_noise_dps_sqrthz                                                    # no human units in the SI view


def test_the_readme_table_and_default_yaml_are_the_schemas():
    """Each key's default and meaning are declared once (its S(...)); the README's table and configs/default.yaml are
    generated from them, so a new observation's keys reach both by `python scripts/config_docs.py` (an extensibility
    review: they were two hand copies that a test only checked for the key's name)."""
    from fusion_eval import config_docs

    sch = schema()
    readme = (ROOT / "README.md").read_text()
    hint = "out of date: run python scripts/config_docs.py"
    assert config_docs.readme_with_table(readme, sch) == readme, hint
    assert config_docs.default_yaml(sch) == (ROOT / "configs" / "default.yaml").read_text(), hint
    assert all(f"`{k}`" in readme for k in sch)
    # the file is a configuration too: read back, it is the defaults
    assert load_config(ROOT / "configs" / "default.yaml") == default_config()
    # a table cell keeps its column: a '|' in a meaning ('|angular rate|') is escaped
    assert "\\|angular rate\\|" in config_docs.readme_table(sch)


def test_exponent_numbers_without_a_point_are_numbers():
    # YAML 1.1 reads 1e-05 as a string; the README's own spelling must work
    cfg = load_config(None, ("imu.gyro_bias_rw_dps2_sqrthz=1e-05", "gnss.noise_std_m=[1e0, 2, 3]"))
    assert cfg["imu"]["gyro_bias_rw_dps2_sqrthz"] == 1e-05 and cfg["gnss"]["noise_std_m"] == [1.0, 2.0, 3.0]
    with pytest.raises(ConfigError, match=">= 0"):
        load_config(None, ("gnss.seed=-1",))


def test_chi2_quantiles_equal_scipy_stats():
    from scipy.stats import chi2

    from fusion_eval.stats import chi2_ppf

    for dof in (1, 2, 3, 6, 15):
        q = np.array([0.025, 0.5, 0.975, 0.9999])
        assert np.array_equal(chi2_ppf(q, dof), chi2.ppf(q, dof))


def test_yaml_mappings_know_the_lines_of_their_keys():
    """Config and manifest errors name the line of the bad key (fusion_eval/yaml_lines.py); the mappings are dicts
    to everything else (equality, JSON, yaml.safe_dump, pickling)."""
    import json
    import pickle

    import yaml

    from fusion_eval import yaml_lines

    d = yaml_lines.load("a: 1\nb:\n  c: 2\n\n  d: [1, 2]\nbase: &x {k: 1}\ne:\n  <<: *x\n  m: 2\n")
    assert d == {"a": 1, "b": {"c": 2, "d": [1, 2]}, "base": {"k": 1}, "e": {"k": 1, "m": 2}}
    assert yaml_lines.at("f.yaml", d["b"], "d") == "f.yaml:5" and yaml_lines.at("f.yaml", d, "e") == "f.yaml:7"
    assert yaml_lines.at("f.yaml", d["e"], "k") == "f.yaml:6"          # a merged key: where it was written
    assert yaml_lines.at("f.yaml", d["b"], "nope") == "f.yaml:3"       # not there: the mapping's own line
    assert yaml_lines.at("--set", {"a": 1}, "a") == "--set"            # not from a file: no line
    assert yaml.safe_load(yaml.safe_dump(d)) == d and json.loads(json.dumps(d)) == d
    assert pickle.loads(pickle.dumps(d))["b"].lines == {"c": 3, "d": 5}
    # the line of the value that counts: a key overridden after a merge names its own place
    d = yaml_lines.load("base: &b\n  x: 1\nderived:\n  <<: *b\n  x: bad\n")
    assert d["derived"]["x"] == "bad" and yaml_lines.at("f", d["derived"], "x") == "f:5"


def test_a_key_given_twice_or_a_yaml_11_oddity_is_refused_with_its_line(tmp_path):
    """YAML loaders keep the last of two equal keys and drop the first without a word: a config with a second
    'filter:' section fused GNSS although the first said use_gnss: false (found by a corrupted-input review).
    YAML 1.1 also reads 1:30 as 90 and 010 as 8; neither is what a configuration means."""
    from fusion_eval.config import parse_file

    for text, line, what in (("filter:\n  use_gnss: false\nimu:\n  gyro_noise_dps_sqrthz: 1.0\nfilter:\n  nhc: true\n", 5,
                              "key 'filter' given twice (first at line 1"),
                             ("gnss:\n  noise_std_m: 1\n  noise_std_m: 2\n", 3, "key 'noise_std_m' given twice (first at line 2"),
                             ("gnss:\n  noise_std_m: 1:30\n", 2, "base-60"), ("gnss:\n  seed: 010\n", 2, "octal")):
        f = tmp_path / "c.yaml"
        f.write_text(text)
        with pytest.raises(ConfigError, match=rf"c.yaml:{line}: .*{re.escape(what)}"):
            parse_file(f)
    f.write_text("gnss:\n  seed: '010'\n  noise_std_m: 0.5\n")             # quoted: text, as asked (then refused by type)
    with pytest.raises(ConfigError, match="seed"):
        parse_file(f)
    # the same on the command line (a review found --set still read 010 as 8); as keys they are names ('01')
    from fusion_eval import yaml_lines
    from fusion_eval.config import parse_sets

    for item, what in (("gnss.seed=010", "octal"), ("gnss.outages_s=[[1:30, 2:00]]", "base-60")):
        with pytest.raises(ConfigError, match=rf"--set '{re.escape(item)}': .* YAML 1.1 {what} number"):
            parse_sets((item,))
    assert yaml_lines.load("settings:\n  01: {a: 1}\n  02: {a: 2}\n") == {"settings": {"01": {"a": 1}, "02": {"a": 2}}}
    with pytest.raises(Exception, match="key 'true' given twice .*as '1', the same key once read"):
        yaml_lines.load("a:\n  1: x\n  true: y\n")


def test_a_key_with_no_value_in_a_file_is_refused_with_its_line(tmp_path):
    (tmp_path / "c.yaml").write_text("gnss:\n  rate_hz:\n")
    with pytest.raises(ConfigError, match=r"c.yaml:2: gnss.rate_hz has no value \(write null for null\)"):
        load_config(tmp_path / "c.yaml")
    (tmp_path / "c.yaml").write_text("gnss:\n  rate_hz: null\n")
    assert load_config(tmp_path / "c.yaml")["gnss"]["rate_hz"] is None


def test_a_run_label_with_a_percent_sign_is_said_as_written(caplog):
    """The label was %-escaped, and a warning without arguments is not %-formatted: '50%%' came out (a review)."""
    import logging

    from fusion_eval.log_context import prefixed

    log = logging.getLogger("fusion_eval.test")
    with caplog.at_level("WARNING"), prefixed("run x (gnss 50% outage)"):
        log.warning("plain")
        log.warning("with %s", "args")
    log.warning("after")
    assert [r.getMessage() for r in caplog.records] == ["run x (gnss 50% outage): plain",
                                                        "run x (gnss 50% outage): with args", "after"]


def test_a_missing_config_file_names_the_shipped_one_of_that_name(tmp_path, monkeypatch):
    """`-c lidar-imu.yaml` said only 'not found' (a student's review): the file of that name under configs/ is named."""
    from fusion_eval.config import read_yaml

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"lidar-imu.yaml: config file not found; did you mean .*configs/lidar-imu.yaml "
                                          r"\(shipped with fusion-eval\)\?"):
        read_yaml(Path("lidar-imu.yaml"))
    with pytest.raises(ConfigError, match=r"no-such.yaml: config file not found$"):
        read_yaml(Path("no-such.yaml"))
