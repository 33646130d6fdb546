"""Open a report in headless Chromium: a screenshot, and whether every image on the page loaded.

The report itself has no scripts; the check loads a copy beside it (so relative figure paths resolve) with a
small script that counts the images that loaded, and reads the count back from the DOM Chromium dumps.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_PROBE = """<script>
window.addEventListener('load', () => {
  const imgs = Array.from(document.images);
  const ok = imgs.filter(i => i.complete && i.naturalWidth > 0).length;
  document.body.setAttribute('data-images', imgs.length + '/' + ok);
});
</script>"""


@dataclass(frozen=True)
class PageCheck:
    screenshot: Path
    images: int
    images_loaded: int
    blank: bool  # the screenshot is (nearly) one colour

    @property
    def ok(self) -> bool:
        return not self.blank and self.images == self.images_loaded


def find_chromium() -> str | None:
    """The Chromium executable on PATH (Debian's ``chromium``), or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    return None


def _chromium(exe: str, *args: str, timeout: float) -> subprocess.CompletedProcess[str]:
    base = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--disable-dev-shm-usage"]
    return subprocess.run([*base, *args], capture_output=True, text=True, timeout=timeout, check=False)


def check_page(page: str | Path, screenshot: str | Path, *, width: int = 1280, height: int = 2400) -> PageCheck:
    """Render ``page`` in headless Chromium, write a screenshot and count the images that loaded."""
    exe = find_chromium()
    if exe is None:
        raise FileNotFoundError("chromium not found on PATH (Debian: apt-get install chromium)")
    page = Path(page).resolve()
    screenshot = Path(screenshot).resolve()
    text = page.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>", 1)
    with tempfile.NamedTemporaryFile("w", suffix=".html", dir=page.parent, delete=False, encoding="utf-8") as fh:
        fh.write(text)
        probe = Path(fh.name)
    try:
        dom = _chromium(exe, "--dump-dom", probe.as_uri(), timeout=120)
        shot = _chromium(
            exe, f"--screenshot={screenshot}", f"--window-size={width},{height}", page.as_uri(), timeout=120
        )
    finally:
        probe.unlink(missing_ok=True)
    if not screenshot.exists():
        raise RuntimeError(f"chromium wrote no screenshot: {shot.stderr.strip()[-500:]}")
    m = re.search(r'data-images="(\d+)/(\d+)"', dom.stdout)
    if m is None:
        raise RuntimeError(f"chromium did not report the page's images: {dom.stderr.strip()[-500:]}")
    from matplotlib.image import imread

    img = imread(screenshot)[..., :3]
    return PageCheck(screenshot, int(m.group(1)), int(m.group(2)), float(np.std(img)) < 0.01)
