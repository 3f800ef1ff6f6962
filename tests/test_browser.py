"""The HTML reports in a real browser: headless Chromium lays them out at 1400 px.

Each page is loaded with a small script that, once the page has loaded, measures the document's
scroll width against the window's and names the elements reaching past the right edge. The
acceptance report (a real ``hil acceptance`` run) and the gap report (``hil gap diagnose
--html`` on the example recording) must not scroll sideways; a report built to provoke
overflow (long unbroken messages, raw-byte parameters, long node ids) must not either. The
screenshots in the README (docs/img/acceptance-report.png, docs/img/gap-report.png) are the
ones these tests take: with ``HIL_README_SCREENSHOTS=1`` they are saved there, otherwise in the
test's temporary folder (a test run leaves the checkout as it found it: the release check of the
figures, which runs the suite, records the commit it checked). Without Chromium the tests skip and
say why (``.ci/run`` installs it).
"""

from __future__ import annotations

import html as htmllib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: where the README's screenshots are saved when asked for (HIL_README_SCREENSHOTS=1)
IMG = ROOT / "docs" / "img"


def screenshot_path(name: str, tmp_path: Path) -> Path:
    return (IMG if os.environ.get("HIL_README_SCREENSHOTS") == "1" else tmp_path) / name


WIDTH_PX = 1400
CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
pytestmark = pytest.mark.skipif(
    CHROMIUM is None,
    reason="headless Chromium is not installed (Debian: apt-get install chromium; "
    ".ci/run installs it): the reports' layout in a browser is NOT checked",
)

#: appended to a copy of the page: after load, the layout figures go into a <pre> that --dump-dom prints
PROBE = """<script>
addEventListener('load', () => {
  const width = document.documentElement.clientWidth;
  const wide = [...document.body.querySelectorAll('*')]
    .filter(e => e.getBoundingClientRect().right > width + 0.5)
    .slice(0, 8)
    .map(e => e.tagName.toLowerCase() + (e.className ? '.' + e.className : '')
              + ' "' + (e.textContent || '').trim().slice(0, 60) + '"');
  const out = document.createElement('pre');
  out.id = 'hil-layout-probe';
  out.textContent = JSON.stringify({scrollWidth: document.documentElement.scrollWidth, clientWidth: width, wide: wide});
  document.body.appendChild(out);
});
</script>"""


def chromium(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    profile = cwd / "chromium-profile"  # its own profile: no lock shared with another browser
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        f"--user-data-dir={profile}",
        "--no-first-run",
        "--disable-extensions",
        *args,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=cwd)


def layout(page: Path, tmp_path: Path) -> dict:
    """The page's scroll width, client width and overflowing elements at WIDTH_PX, as Chromium lays it out."""
    probe = tmp_path / f"probe-{page.name}"
    text = page.read_text()
    probe.write_text(text.replace("</body>", PROBE + "</body>") if "</body>" in text else text + PROBE)
    run = chromium(
        f"--window-size={WIDTH_PX},1000", "--virtual-time-budget=10000", "--dump-dom", probe.as_uri(), cwd=tmp_path
    )
    found = re.search(r'<pre id="hil-layout-probe">(.*?)</pre>', run.stdout, re.S)
    assert found, f"Chromium did not run the layout probe on {page} (exit {run.returncode}): {run.stderr[-800:]}"
    return json.loads(htmllib.unescape(found.group(1)))


def assert_no_horizontal_overflow(page: Path, tmp_path: Path) -> None:
    figures = layout(page, tmp_path)
    assert figures["clientWidth"] >= WIDTH_PX - 20, (
        f"the window is {figures['clientWidth']} px wide, not about {WIDTH_PX}"
    )
    assert figures["scrollWidth"] <= figures["clientWidth"], (
        f"{page.name} scrolls sideways at {WIDTH_PX} px: content {figures['scrollWidth']} px in a "
        f"{figures['clientWidth']} px window; "
        f"past the edge: {figures['wide']}"
    )


def screenshot(page: Path, png: Path, tmp_path: Path, height_px: int = 1000) -> None:
    png.parent.mkdir(parents=True, exist_ok=True)
    run = chromium(
        f"--window-size={WIDTH_PX},{height_px}",
        "--virtual-time-budget=10000",
        f"--screenshot={png}",
        page.as_uri(),
        cwd=tmp_path,
    )
    assert png.is_file() and png.stat().st_size > 10_000, (
        f"no screenshot of {page} (exit {run.returncode}): {run.stderr[-800:]}"
    )


def hil(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run(
        [sys.executable, "-m", "hil", *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=1800
    )


@pytest.fixture(scope="module")
def acceptance_run(default_acceptance):
    """The default ``hil acceptance`` run (tests/conftest.py: one a session)."""
    return default_acceptance


def test_acceptance_report_fits_1400_px_and_gives_the_readme_screenshot(acceptance_run, tmp_path):
    _, reports = acceptance_run
    page = reports / "hil-report.html"
    assert_no_horizontal_overflow(page, tmp_path)
    screenshot(page, screenshot_path("acceptance-report.png", tmp_path), tmp_path)


def test_gap_report_fits_1400_px_and_gives_the_readme_screenshot(tmp_path):
    page = tmp_path / "gap.html"
    run = hil("gap", "diagnose", "examples/bench-recording", "--html", str(page), cwd=ROOT)  # as the README says
    assert run.returncode == 0, run.stderr
    assert_no_horizontal_overflow(page, tmp_path)
    screenshot(page, screenshot_path("gap-report.png", tmp_path), tmp_path)


#: everything that once ran past the card edge: unbroken blobs, raw bytes as parameters, long ids
HOSTILE_SUITE = """
import pytest

BLOB = "AXicY2BgYGBkZGJmYWVjZ2Dk4ubh5eMXEBQSFhEVE5eQlJKWkZWTV1BUUlZRVVPX0NTS1tHV0zcwNDI2MTUzt7C0sra"  * 6

@pytest.mark.requirement("REQ-X-001")
@pytest.mark.parametrize("pdu", [b"\\x03\\xff\\xf0\\x00\\x01", "a" * 180])
def test_a_rather_long_test_name_that_goes_on_and_on_to_see_whether_the_matrix_column_wraps_it(
        pdu, hil_budget, hil_evidence):
    hil_evidence.text("a long line", BLOB)
    hil_evidence.table("a wide table", ["column_" + str(i) for i in range(14)], [[BLOB[:40]] * 14])
    hil_budget("a_budget_with_a_rather_long_name_for_the_traceability_matrix", 0.1)

@pytest.mark.requirement("REQ-X-002")
@pytest.mark.xfail(reason="known: " + BLOB)
def test_known_failure():
    raise AssertionError("You can reproduce this example by temporarily adding "
                         "@reproduce_failure('6.1', b'" + BLOB + "')")

@pytest.mark.requirement("REQ-X-002")
def test_failure_with_a_long_message():
    assert False, BLOB
"""
HOSTILE_BUDGETS = """
[a_budget_with_a_rather_long_name_for_the_traceability_matrix]
requirement = "REQ-X-001"
unit = "deg_e"
limit = 0.5
description = "a budget only for this test"
"""


def test_a_report_built_to_overflow_still_fits_1400_px(tmp_path):
    (tmp_path / "suite").mkdir()
    (tmp_path / "suite" / "test_hostile.py").write_text(HOSTILE_SUITE)
    (tmp_path / "budgets.toml").write_text(HOSTILE_BUDGETS)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "suite",
            "-q",
            "-p",
            "no:cacheprovider",
            "--hil-report-dir",
            "rep",
            "--hil-budgets",
            "budgets.toml",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    page = tmp_path / "rep" / "hil-report.html"
    text = page.read_text()
    # a raw-bytes parameter reads as hex in the matrix, never as \x03\xff
    assert "wraps it · 03 ff f0 00 01</a>" in text, "raw bytes shown as a test name"
    assert_no_horizontal_overflow(page, tmp_path)


def test_printing_gives_a_document_to_sign(acceptance_run, tmp_path):
    _, reports = acceptance_run
    pdf = tmp_path / "report.pdf"
    run = chromium(
        "--no-pdf-header-footer", f"--print-to-pdf={pdf}", (reports / "hil-report.html").as_uri(), cwd=tmp_path
    )
    assert pdf.is_file() and pdf.read_bytes()[:5] == b"%PDF-", f"no PDF (exit {run.returncode}): {run.stderr[-800:]}"
    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (poppler-utils) is not installed: the PDF's text is NOT checked")
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True, text=True, check=True).stdout
    pages = text.count("\f")
    assert "Review and approval" in text and "signature" in text, "the printed report has no sign-off block"
    assert "Requirement traceability" in text and re.search(r"HIL compliance report\s+(PASS|FAIL|INCOMPLETE)", text)
    assert 2 <= pages <= 60, f"{pages} printed pages"
