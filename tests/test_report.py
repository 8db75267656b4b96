"""The report layer's formats: tables (Markdown, LaTeX), JUnit XML, provenance, report.md's wording, report.html
(self-contained; rendered in headless Chromium where it is installed)."""

from __future__ import annotations

import base64
import hashlib
import os
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion_eval import provenance, tables
from fusion_eval.commands.check import Row, junit
from fusion_eval.report import html


def test_markdown_table_aligns_escapes_and_formats():
    lines = tables.markdown(["name", "value [m]"], [["a|b", 1.23456], ["c", None]], decimals=2)
    assert lines[1].startswith("|:") and lines[1].endswith(":|")          # left, then right aligned
    assert re.search(r"\| a\\\|b +\| +1\.23 \|", lines[2])                 # '|' escaped, 2 decimals
    assert re.search(r"\| +n/a \|$", lines[3])
    with pytest.raises(ValueError):
        tables.markdown(["a", "b"], [[1, 2]], align="lrl")


def test_latex_table_is_booktabs_and_escaped():
    tex = tables.latex(["estimate", "error [%]"], [["`fused_x`", 0.5], ["a&b", None]], caption="APE of 95 % `x_y`",
                       label="tab:t")
    assert "\\toprule" in tex and "\\midrule" in tex and "\\bottomrule" in tex and "{lr}" in tex
    assert "fused\\_x" in tex and "a\\&b" in tex and "error [\\%]" in tex and "`" not in tex
    assert "\\caption{APE of 95 \\% x\\_y}" in tex and "\\label{tab:t}" in tex
    assert tex.count("\\begin{table}") == 1 and tex.count("\\end{table}") == 1


def test_junit_is_valid_xml_for_any_metric_name():
    xml = junit([Row("a<b&\"c\"", 1.0, 2.0, "REGRESSION"), Row("fused.ape.rmse", 1.0, 1.0, "ok")],
                [("x < y", False, "x (1) < y (0)"), ("y > 0", True, "y (1) > 0")])
    root = ET.fromstring(xml.encode())
    assert root.tag == "testsuite" and root.get("tests") == "4" and root.get("failures") == "2"
    cases = root.findall("testcase")
    assert cases[0].get("name") == 'a<b&"c"' and cases[0].find("failure") is not None
    assert cases[1].find("failure") is None and cases[3].find("failure") is None
    assert "rule fails" in cases[2].find("failure").get("message")


def test_provenance_date_honours_source_date_epoch(monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    assert provenance.date_utc() == "2023-11-14 22:13 UTC"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "not-a-number")       # ignored, not an error
    assert provenance.date_utc().endswith(" UTC")


def test_input_checksums_follow_the_content(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "a.txt").write_text("1 2 3\n")
    (tmp_path / "b.txt").write_text("x\n")
    desc = {"path": str(tmp_path), "streams": {"imu": {"path": "d"}, "lidar": {"path": "b.txt", "times": {"file": "b.txt"}},
                                               "gnss": {"path": "missing.txt"}}}
    rows = {Path(r["path"]).name: r for r in provenance.input_files(desc)}
    assert rows["d"]["files"] == 1 and rows["b.txt"]["streams"] == ["lidar", "lidar"]
    assert rows["missing.txt"]["sha256"] is None
    assert rows["b.txt"]["sha256"] == hashlib.sha256(b"x\n").hexdigest()
    before = rows["d"]["sha256"]
    (tmp_path / "d" / "a.txt").write_text("1 2 4\n")
    os.utime(tmp_path / "d", ns=(1, 1))      # a folder's digest is keyed on its own stat too: force a new key
    assert {Path(r["path"]).name: r for r in provenance.input_files(desc)}["d"]["sha256"] != before


def _png(path: Path, seed: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot(np.random.default_rng(seed).normal(size=20))
    fig.savefig(path)
    plt.close(fig)


def test_html_page_is_self_contained(tmp_path):
    _png(tmp_path / "a.png", 0)
    _png(tmp_path / "b.png", 1)
    md = "# fusion-eval run: x\n\nfusion-eval 0.1.0, 2026-01-01 00:00 UTC: `fusion-eval run`\n\n## Summary\n\n" + \
        "\n".join(tables.markdown(["estimate", "APE [m]"], [["fused", 0.7]])) + "\n\n![a](a.png)\n![gone](gone.png)\n"
    page = html.page(md, tmp_path, images=["a.png", "b.png"], inputs=[{"streams": ["imu"], "path": "oxts", "sha256": "ab" * 32,
                                                                       "bytes": 1234, "files": 3}])
    assert "<title>fusion-eval run: x</title>" in page and "<table>" in page and "APE [m]" in page
    srcs = re.findall(r'src="([^"]+)"', page)
    assert len(srcs) == 2 and all(s.startswith("data:image/png;base64,") for s in srcs)      # a.png once, b.png added
    assert base64.b64decode(srcs[0].split(",", 1)[1]) == (tmp_path / "a.png").read_bytes()
    assert "figure gone.png was not written" in page
    assert not re.search(r"(src|href)=\"(https?:)?//", page)          # nothing fetched from a network
    assert "ab" * 32 in page and "1,234" in page and 'id="provenance"' in page
    assert page.count("2026-01-01 00:00 UTC") == 0                       # the body's header line is the page's header


def test_run_writes_report_html_tex_and_plain_wording(slice_run):
    md = (slice_run / "report.md").read_text()
    assert md.splitlines()[2].startswith("fusion-eval ") and " UTC: `" in md.splitlines()[2]
    assert "outages none" not in md and "{'" not in md and "no outages" in md
    assert "Time offsets added to each stream's stamps: none" in md
    tex = (slice_run / "metrics.tex").read_text()
    assert "\\toprule" in tex and "imu\\_only" in tex
    page = (slice_run / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "Summary against ground truth" in page
    n_png = len([p for p in slice_run.iterdir() if p.suffix == ".png"])
    assert n_png > 0 and page.count("data:image/png;base64,") == n_png
    assert "oxts" in page and re.search(r"<code>[0-9a-f]{64}</code>", page)
    # an 'auto' the data settled shows what it became, with the value the preparation applied
    settled = yaml.safe_load((slice_run / "config.resolved.yaml").read_text())["applied"]["auto_settled"]
    assert f"discretization: auto  # -> {settled['filter.discretization']}" in md
    assert f"gravity_mps2: auto  # -> {settled['filter.gravity_mps2']:.6g}" in md
    assert 9.7 < settled["filter.gravity_mps2"] < 9.9


def test_run_metrics_json_says_what_made_its_figures(slice_run, kitti_slice):
    """metrics.json carries the version, the code digest, the command and every input file's sha256 (they were only in
    report.html, which a script comparing two metrics.json files does not read)."""
    import json

    from fusion_eval import provenance

    made = json.loads((slice_run / "metrics.json").read_text())["provenance"]
    assert made["code"] == provenance.code_id() and made["version"] and " UTC" in made["date"]
    rows = {Path(r["path"]).name: r for r in made["inputs"]}
    lidar = next(r for r in made["inputs"] if "lidar" in r["streams"] and Path(r["path"]).is_file()
                 and Path(r["path"]).name != "calib.txt")
    assert lidar["sha256"] == hashlib.sha256(Path(lidar["path"]).read_bytes()).hexdigest()
    assert rows["oxts"]["files"] > 800 and set(rows["oxts"]["streams"]) >= {"imu", "gnss"}
    # the manifest too (its origin, extrinsics and offsets move the figures), and the configuration as resolved
    assert rows["dataset.yaml"]["streams"] == ["manifest"]
    assert made["config_sha256"] == hashlib.sha256((slice_run / "config.resolved.yaml").read_bytes()).hexdigest()


def test_evaluate_metrics_json_names_its_input_files(slice_run, tmp_path):
    import json

    from click.testing import CliRunner

    from fusion_eval.cli import main

    gt, est = slice_run / "groundtruth.tum", slice_run / "fused.tum"
    r = CliRunner().invoke(main, ["-q", "evaluate", str(gt), str(est), "--no-plots", "--out", str(tmp_path / "e")])
    assert r.exit_code == 0, r.output
    made = json.loads((tmp_path / "e" / "metrics.json").read_text())["provenance"]
    assert [(row["streams"], row["sha256"]) for row in made["inputs"]] == \
        [(["reference"], hashlib.sha256(gt.read_bytes()).hexdigest()), (["estimate"], hashlib.sha256(est.read_bytes()).hexdigest())]


def _console(stderr: str) -> list[str]:
    """The page's console messages in Chromium's log (``--enable-logging=stderr``: ``INFO:CONSOLE(...)`` lines)."""
    return [ln for ln in stderr.splitlines() if ":CONSOLE" in ln or "Uncaught" in ln]


def _chromium() -> str | None:
    return next((c for c in ("chromium", "chromium-browser", "google-chrome") if shutil.which(c)), None)


@pytest.mark.slow
@pytest.mark.skipif(_chromium() is None, reason="no headless Chromium here (Debian: apt-get install chromium; .ci/run "
                                                 "installs it where it can)")
def test_report_html_renders_in_chromium_without_console_errors(slice_run, tmp_path):
    """Render the run's page in headless Chromium: no console errors, the table and every figure laid out and
    decoded (the page's own DOM, dumped after load), and a screenshot that is not blank."""
    exe = _chromium()
    url = (slice_run / "report.html").resolve().as_uri()
    common = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
              "--disable-extensions", f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000"]
    # a probe appended to a copy of the page: it writes what it found into the DOM that --dump-dom prints
    probe = tmp_path / "probe.html"
    probe.write_text((slice_run / "report.html").read_text().replace("</body>", """<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images), t = document.querySelector('main table');
  var r = t ? t.getBoundingClientRect() : null;
  var out = document.createElement('pre'); out.id = 'probe';
  out.textContent = JSON.stringify({images: imgs.length,
    decoded: imgs.filter(function (i) { return i.complete && i.naturalWidth > 0 && i.getBoundingClientRect().width > 50; }).length,
    table_w: r ? r.width : 0, table_h: r ? r.height : 0});
  document.body.appendChild(out);
});
</script></body>"""))
    dom = subprocess.run(common + ["--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120)
    import json
    found = json.loads(re.search(r'<pre id="probe">(.*?)</pre>', dom.stdout).group(1).replace("&quot;", '"'))
    assert found["images"] >= 3 and found["decoded"] == found["images"], found
    assert found["table_w"] > 300 and found["table_h"] > 60, found

    shot = tmp_path / "shot.png"
    r = subprocess.run(common + ["--enable-logging=stderr", "--v=0", "--window-size=1400,2000", f"--screenshot={shot}", url],
                       capture_output=True, text=True, timeout=120)
    assert not _console(r.stderr), _console(r.stderr)
    # the same detector on a page with an error does see it (the check can fail)
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><p>x</p><script>undefinedFunction();</script></body></html>")
    r_bad = subprocess.run(common + ["--enable-logging=stderr", "--v=0", f"--screenshot={tmp_path / 'bad.png'}", bad.as_uri()],
                           capture_output=True, text=True, timeout=120)
    assert any("undefinedFunction" in ln for ln in _console(r_bad.stderr)), r_bad.stderr[-2000:]
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)
    assert img.shape[0] == 2000 and img.shape[1] == 1400
    assert img[..., :3].std() > 0.05          # not a blank page: text, tables and plots
    keep = os.environ.get("FUSION_EVAL_SCREENSHOT_DIR")       # CI or a reviewer may keep the screenshot to look at
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, Path(keep) / "report_html.png")


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="no pdflatex here (Debian: texlive-latex-recommended)")
def test_metrics_tex_compiles_and_fits_the_page(slice_run, tmp_path):
    doc = tmp_path / "d.tex"
    doc.write_text("\\documentclass{article}\\usepackage{booktabs}\\usepackage{graphicx}\\begin{document}"
                   f"\\input{{{slice_run / 'metrics.tex'}}}\\end{{document}}\n")
    r = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", doc.name], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:]
    log = (tmp_path / "d.log").read_text(errors="replace")
    assert "Overfull \\hbox" not in log and (tmp_path / "d.pdf").stat().st_size > 1000


def test_the_report_says_when_the_filter_scales_an_estimated_noise():
    from fusion_eval.report.markdown import _config_block, _estimates

    applied = {"imu_noise": {"accel_noise_mps2_sqrthz": 0.05, "gyro_noise_dps_sqrthz": 0.1},
               "auto_settled": {"imu.accel_noise_mps2_sqrthz": 0.05, "imu.gyro_noise_dps_sqrthz": 0.2}}
    line = next(ln for ln in _estimates(applied) if "IMU white noise" in ln)
    assert "accelerometer 0.0500 m/s^2/sqrt(Hz), gyro 0.1000" in line and "uses 2x that: imu.gyro_noise_scale" in line
    assert line.count("the filter uses") == 1                      # the unscaled one says nothing more
    block = _config_block({"imu": {"gyro_noise_dps_sqrthz": "auto", "accel_noise_scale": 1.0},
                           "lidar": {"noise_adapt": "auto"}}, applied["auto_settled"])
    assert "gyro_noise_dps_sqrthz: auto  # -> 0.2" in block
    assert "noise_adapt: auto\n" in block + "\n"                   # not settled for the run: no value shown


def test_no_verdict_between_errors_under_a_millimetre(tmp_path):
    """An ideal (noise-free) simulated drive's report said 'fusion is worse than lidar alone, 19953.2 % higher' of
    5e-5 m against 3e-7 m (found by a new-user review)."""
    from click.testing import CliRunner

    from fusion_eval.cli import main
    from fusion_eval.simulate.dataset import simulate

    simulate(tmp_path / "sim", "urban", 20.0, 1, "ideal", ("output.layout=csv",), jobs=1)
    r = CliRunner().invoke(main, ["-q", "run", str(tmp_path / "sim"), "--no-plots", "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    md = (tmp_path / "o" / "report.md").read_text()
    assert "no verdict" in md and "% higher" not in md and "% lower" not in md


@pytest.mark.slow
def test_the_summary_heading_and_captions_name_the_alignment_used(kitti_slice, tmp_path):
    """'Summary against ground truth (evo, no alignment)' headed se3-aligned figures (found by a new-user review)."""
    from click.testing import CliRunner

    import fusion_eval as fe
    from fusion_eval.cli import main

    fe.run(kitti_slice, overrides={"evaluation.alignment": "se3"}).write(tmp_path / "o")
    assert "## Summary against ground truth (evo, SE(3) alignment (Umeyama))" in (tmp_path / "o" / "report.md").read_text()
    assert "(evo, SE(3) alignment (Umeyama))." in (tmp_path / "o" / "metrics.tex").read_text()
    r = CliRunner().invoke(main, ["-q", "compare", str(kitti_slice), "--variants", "eskf", "--set",
                                  "evaluation.alignment=sim3", "--out", str(tmp_path / "c"), "--no-plots"])
    assert r.exit_code == 0, r.output
    assert "(evo, Sim(3) alignment (Umeyama, with scale))" in (tmp_path / "c" / "compare.md").read_text()
    assert "Sim(3) alignment" in (tmp_path / "c" / "compare.tex").read_text()


def test_a_run_without_gnss_fusion_says_its_gnss_fixes_were_not_fused(kitti_slice, tmp_path):
    """lidar-imu.yaml's report said '464 fixes used' and 'std given to the filter' in its GNSS section, read as fused
    (a student's review), though its header said 'GNSS fused: no'."""
    from click.testing import CliRunner

    from fusion_eval.cli import main

    r = CliRunner().invoke(main, ["-q", "run", str(kitti_slice), "--out", str(tmp_path / "o"), "--no-plots",
                                  "--set", "filter.use_gnss=false"])
    assert r.exit_code == 0, r.output
    text = (tmp_path / "o" / "report.md").read_text()
    assert "The filter does not fuse GNSS in this run (`filter.use_gnss: false`)" in text


def test_a_verdict_won_on_ape_says_where_the_relative_figures_lose():
    """kitti-00's fused estimate is 89.5 % better than the lidar in APE and worse in RPE over 100 m and KITTI drift;
    the verdict said only the first (a student's review)."""
    from types import SimpleNamespace as NS

    from fusion_eval.report.markdown import _relative_worse

    def ev(rpe, drift):
        return NS(metrics={"rpe_100m": {"translation_m": {"rmse": rpe}}}, drift={"t_err_pct": drift})
    cfg = {"evaluation": {"rpe_delta_m": 100.0}}
    got = _relative_worse({"fused": ev(0.906, 0.494), "lidar": ev(0.850, 0.462)}, "fused", "lidar", cfg)
    assert got == "; but worse on RPE over 100 m (0.906 against 0.85 m) and KITTI drift (0.494 against 0.462 %)"
    assert _relative_worse({"fused": ev(0.8, 0.4), "lidar": ev(0.85, 0.46)}, "fused", "lidar", cfg) == ""
    assert _relative_worse({"fused": ev(0.8, None), "gnss": NS(metrics={}, drift=None)}, "fused", "gnss", cfg) == ""


def test_a_track_shorter_than_one_segment_says_so_instead_of_an_empty_list():
    """fr2/desk (a few metres) ended its report with 'Worst segments for fr2_desk_ORB: .' (a review)."""
    from fusion_eval.report.markdown import segments_section

    seg = {"by": "distance", "length": 100.0, "primary": "est", "secondary": None, "worst": [],
           "segments": [{"index": 0, "start_m": 0.0, "end_m": 12.0, "start_s": 0.0, "end_s": 30.0,
                         "rmse_m": {"est": 0.006}}]}
    text = "\n".join(segments_section({"segments": seg}))
    assert "Worst segments" not in text and "No segment of est is ranked: the track is shorter than one window of 100 m" in text
    seg["worst"] = [0]
    assert "Worst segments for est: 0 (0-12 m, 0.006 m)." in "\n".join(segments_section({"segments": seg}))


def test_the_smoother_line_gives_the_bytes_per_clone_too(kitti_slice, tmp_path):
    """'35.5 MB (5849 bytes per epoch)' over 4409 epochs did not multiply out: the clones' 2200 bytes each were not
    said (a review)."""
    import fusion_eval as fe

    res = fe.run(fe.load_dataset(kitti_slice), overrides={"smoother.method": "rts", "output.plots": False})
    sm = res.metrics["smoother"]
    assert sm["record_bytes"] == sm["epochs"] * sm["bytes_per_epoch"] + sm["clones"] * sm["bytes_per_clone"]
    res.write(tmp_path / "o")
    line = next(ln for ln in (tmp_path / "o" / "report.md").read_text().splitlines() if "Smoother: **rts**" in ln)
    assert f"({sm['bytes_per_epoch']} bytes per epoch, {sm['bytes_per_clone']} per clone)" in line


def test_time_offsets_are_said_in_seconds_when_they_are_a_clock_epoch():
    """A seconds-of-day GNSS put on POSIX time read 'gnss +1317600000000.0 ms' (an own-data review)."""
    from fusion_eval.report.markdown import _offsets

    assert _offsets({"gnss": 1317600000.0, "lidar": 0.0}) == "gnss +1317600000.000 s; the other streams none"
    assert _offsets({"lidar": -0.0588}) == "lidar -58.8 ms; the other streams none"


def test_html_shows_wide_figures_and_time_series_at_the_pages_width(tmp_path):
    """Figures side by side are ~480 px wide: a time series (the APE over time, 1320 x 495 px) had a legend no one
    could read without a click (a plot review). Wide or elongated figures start at the page's width."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for name, size in (("series.png", (12, 4.5)), ("square.png", (6, 6)), ("panels.png", (14, 9))):
        fig = plt.figure(figsize=size)
        fig.savefig(tmp_path / name, dpi=110)
        plt.close(fig)
    md = "# fusion-eval run: x\n\n![s](series.png)\n![q](square.png)\n![p](panels.png)\n"
    page = html.page(md, tmp_path)
    kinds = dict(re.findall(r'<figure( class="wide")?><img alt="([^"]*)"', page)[i][::-1] for i in range(3))
    assert kinds == {"s": ' class="wide"', "q": "", "p": ' class="wide"'}


def test_a_drive_of_no_car_says_why_the_constraint_is_off_and_not_what_a_car_does(tmp_path):
    """A drone's report spoke of the non-holonomic constraint as of a car's ('wherever the car does not slip') with the
    constraint off, and never said why it was off (a non-car review)."""
    import fusion_eval as fe
    from fusion_eval.report.markdown import consistency_section
    from fusion_eval.simulate.dataset import simulate

    simulate(tmp_path / "s", "urban", 30.0, 0, "automotive", (), jobs=1)     # the simulator declares no platform
    m = fe.run(tmp_path / "s").metrics
    assert m["preprocessing"]["nhc"].startswith("off (the dataset's platform is not declared")
    assert "nhc" not in m["nis"] and not any("slip" in ln for ln in consistency_section(m))
    car = {**m, "nis": {**m["nis"], "nhc": {"mean": 0.5, "dof": 2, "fraction_in_95": 0.9, "epochs": 10,
                                             "bounds_95": [0.05, 7.4]}}}
    assert any("wherever the vehicle does not slip" in ln for ln in consistency_section(car))
