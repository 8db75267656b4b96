"""The package as users get it: every code package listed, and a wheel (not the checkout) that runs the
default, compares shipped variants, runs a shipped sweep and the README's API example from another directory."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import ROOT

try:                                   # Python 3.11+
    import tomllib
except ModuleNotFoundError:            # pragma: no cover
    tomllib = None


def test_every_code_package_is_listed_in_pyproject():
    if tomllib is None:
        pytest.skip("needs Python 3.11's tomllib")
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "fusion_eval").rglob("__init__.py")}
    assert found <= listed, f"packages missing from pyproject.toml: {sorted(found - listed)}"


def _api_example() -> str:
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Python API"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.fixture(scope="module")
def wheel_site(tmp_path_factory) -> Path:
    """The built wheel, unpacked: the package as pip installs it, without the checkout beside it."""
    tmp = tmp_path_factory.mktemp("wheel")
    # built from a copy of the files git tracks (as a clean clone would be), so that nothing a local build left
    # behind (build/, stray modules) can slip into the wheel
    src = tmp / "src"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.split(b"\0")
    for f in filter(None, files):
        p = ROOT / f.decode()
        if p.is_file():
            (src / f.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(p, src / f.decode())
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp / "w"), str(src)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"the wheel does not build: {r.stderr.strip()}"
    whl = next((tmp / "w").glob("fusion_eval-*.whl"))
    site = tmp / "site"
    with zipfile.ZipFile(whl) as z:
        names = z.namelist()
        assert "fusion_eval/_shipped/data/kitti-00/dataset.yaml" in names
        assert "fusion_eval/_shipped/configs/sweeps/noise5.yaml" in names
        assert "fusion_eval/_shipped/configs/variants/nominal.yaml" in names
        assert "fusion_eval/_shipped/configs/tune/noise.yaml" in names
        tracked = {f"fusion_eval/{p.relative_to(ROOT / 'fusion_eval')}" for p in (ROOT / "fusion_eval").rglob("*.py")}
        assert {n for n in names if n.startswith("fusion_eval/") and n.endswith(".py")} <= tracked
        z.extractall(site)
    _warm_numba_cache(site)
    return site


def _warm_numba_cache(site: Path) -> None:
    """The wheel's kernels are the checkout's (the same files): numba's cache that this test session (or an earlier
    one) built beside the checkout's sources is copied beside the wheel's, with the sources' modification times (its
    index is keyed by them), so that the test runs the wheel's commands rather than numba's compiler a second time
    (about 80 s of CI). A kernel not cached yet is compiled in the wheel's folder, as on a user's first run. With
    NUMBA_CACHE_DIR set the cache lies elsewhere, under the sources' paths, and nothing is copied."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    for src in (ROOT / "fusion_eval").rglob("*.py"):
        dst = site / src.relative_to(ROOT)
        if dst.is_file() and dst.read_bytes() == src.read_bytes():
            st = src.stat()
            os.utime(dst, ns=(st.st_atime_ns, st.st_mtime_ns))
    for cached in (ROOT / "fusion_eval").rglob("__pycache__/*.nb[ic]"):
        dst = site / cached.relative_to(ROOT)
        if dst.parent.parent.is_dir():
            dst.parent.mkdir(exist_ok=True)
            shutil.copy2(cached, dst)


def _run(site: Path, cwd: Path, *args: str, code: str | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site)}
    cmd = [sys.executable, "-c", code] if code else [sys.executable, "-m", "fusion_eval", *args]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


@pytest.mark.slow
def test_the_wheel_works_from_any_directory(wheel_site, tmp_path):
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    r = _run(wheel_site, cwd, code="import fusion_eval, sys; print(fusion_eval.__file__)")
    assert r.returncode == 0 and r.stdout.strip().startswith(str(wheel_site)), r.stdout + r.stderr
    r = _run(wheel_site, cwd, "-q", "run", "--out", "X", "--no-plots")
    assert r.returncode == 0 and (cwd / "X" / "metrics.json").exists(), r.stderr
    # shipped variants of one formulation: another would compile its own loop in this fresh site (~20 s of CI)
    r = _run(wheel_site, cwd, "-q", "compare", "--variants", "eskf,no-nhc", "--out", "C", "--no-plots")
    assert r.returncode == 0 and (cwd / "C" / "compare.md").exists(), r.stderr
    r = _run(wheel_site, cwd, "-q", "sweep", "--grid", "noise5", "--out", "S", "--no-plots", "--jobs", "2")
    assert r.returncode == 0, r.stderr
    rows = (cwd / "S" / "sweep.csv").read_text().splitlines()
    assert len(rows) == 7 and all(",ok," in row for row in rows[1:]), rows
    r = _run(wheel_site, cwd, "-q", "tune", "--space", "noise", "--objective", "nll", "--trials", "2", "-j", "1",
             "--out", "T", "--no-plots")
    assert r.returncode == 0 and (cwd / "T" / "best.yaml").exists(), r.stderr
    r = _run(wheel_site, cwd, code=_api_example())
    assert r.returncode == 0, r.stderr
    assert (cwd / "results" / "api-run" / "metrics.json").exists() and len(r.stdout.split()) == 2


def test_numba_compiles_at_o2_unless_the_user_says_otherwise():
    """The package sets NUMBA_OPT=2 before numba's import (a first run's compilation in 0.71x the time, the replay as
    fast); a value the user set is kept."""
    code = "import fusion_eval, numba.core.config as c; print(int(c.OPT))"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_OPT"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "2"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "NUMBA_OPT": "3"}, capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "3"


def test_caches_go_to_the_temporary_folder_where_nothing_else_can_be_written(monkeypatch, tmp_path):
    """A read-only install with an unwritable home stopped every data command with numba's "no locator available"
    traceback, and matplotlib warned four times a run (a failure-injection review); a user's own setting is kept."""
    import tempfile

    import fusion_eval

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("HOME", str(blocker / "home"))               # under a file: nothing there can be made
    for var in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "NUMBA_CACHE_DIR", "MPLCONFIGDIR"):
        monkeypatch.delenv(var, raising=False)
    pkg = str(Path(fusion_eval.__file__).parent)
    real = fusion_eval._writable
    monkeypatch.setattr(fusion_eval, "_writable", lambda p: False if p.startswith(pkg) else real(p))   # read-only install
    fusion_eval._caches_in_temp()
    assert os.environ["NUMBA_CACHE_DIR"].startswith(tempfile.gettempdir())
    assert os.environ["MPLCONFIGDIR"].startswith(tempfile.gettempdir())
    monkeypatch.setenv("MPLCONFIGDIR", str(tmp_path / "mine"))
    monkeypatch.setenv("HOME", str(tmp_path))                        # a writable home: numba's user cache is used
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    fusion_eval._caches_in_temp()
    assert "NUMBA_CACHE_DIR" not in os.environ and os.environ["MPLCONFIGDIR"] == str(tmp_path / "mine")


def test_a_temporary_cache_folder_is_used_only_if_private(monkeypatch, tmp_path):
    """At a predictable path in the shared temporary folder another user could make the folder first and leave code
    there that numba's cache loads (a diff review): only a private folder of this user's, not a link, is used."""
    import tempfile

    import fusion_eval

    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    uid = os.getuid()
    made = fusion_eval._private_temp("fe-a")
    assert made == str(tmp_path / f"fe-a-{uid}") and (os.stat(made).st_mode & 0o777) == 0o700
    (tmp_path / f"fe-b-{uid}").mkdir(mode=0o777)
    os.chmod(tmp_path / f"fe-b-{uid}", 0o777)                          # writable by others
    (tmp_path / "elsewhere").mkdir(mode=0o700)
    (tmp_path / f"fe-c-{uid}").symlink_to(tmp_path / "elsewhere")     # a link
    assert fusion_eval._private_temp("fe-b") is None and fusion_eval._private_temp("fe-c") is None
    # the caches take the next fixed name when the first is not private, not a new random folder on every import
    (tmp_path / f"fusion-eval-numba-{uid}").mkdir(mode=0o777)
    os.chmod(tmp_path / f"fusion-eval-numba-{uid}", 0o777)
    for var in ("NUMBA_CACHE_DIR", "MPLCONFIGDIR"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(fusion_eval, "_writable", lambda p: False)
    fusion_eval._caches_in_temp()
    assert os.environ["NUMBA_CACHE_DIR"] == str(tmp_path / f"fusion-eval-numba-1-{uid}")


def test_the_code_digest_is_of_the_python_sources_alone(tmp_path):
    """An editable install and a wheel of one commit had two code digests: the wheel's shipped configurations and data
    (``_shipped/``, 4,500 OXTS files read on every run) entered it. Only the package's Python sources do."""
    from fusion_eval import provenance

    pkg = Path(provenance.__file__).resolve().parent
    copy = tmp_path / "fusion_eval"
    shutil.copytree(pkg, copy, ignore=shutil.ignore_patterns("__pycache__", "_shipped"))
    (copy / "_shipped" / "configs").mkdir(parents=True)                  # as a wheel holds them
    (copy / "_shipped" / "configs" / "default.yaml").write_text("x: 1\n", encoding="utf-8")
    (copy / "_shipped" / "x.py").write_text("x = 1\n", encoding="utf-8")
    (copy / "notes.txt").write_text("not code\n", encoding="utf-8")
    assert provenance.code_id(copy) == provenance.code_id()
    (copy / "session.py").write_text((copy / "session.py").read_text(encoding="utf-8") + "# changed\n", encoding="utf-8")
    provenance.code_id.cache_clear()
    assert provenance.code_id(copy) != provenance.code_id()
