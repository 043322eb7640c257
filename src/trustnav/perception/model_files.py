"""Model files that are not ours (the LOOKING weights, the YOLOX-Nano detector): where a checkout
and the user cache keep them, and the one-time download into the cache."""

from __future__ import annotations

import hashlib
import os
import sys
import urllib.request
from pathlib import Path

__all__ = ["cache_path", "checkout_paths", "download", "find_or_download"]


def checkout_paths(folder: str, name: str) -> list[Path]:
    """``../shared/models/<folder>/<name>`` beside the working directory and beside each parent of
    this package (a development checkout)."""
    here = Path(__file__).resolve()
    return [root.parent / "shared" / "models" / folder / name for root in (Path.cwd(), *here.parents)]


def cache_path(name: str) -> Path:
    """The user cache's copy of a model file: ``$XDG_CACHE_HOME/trustnav/<name>`` (~/.cache)."""
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "trustnav" / name


def find_or_download(
    candidates: list[Path],
    cache: Path,
    *,
    allow: bool,
    missing: str,
    notice: str,
    url: str,
    what: str,
    hint: str,
    sha256: str | None = None,
    timeout: float = 60.0,
) -> Path:
    """The first of ``candidates`` that is a file; else, with ``allow``, ``url`` fetched once into
    ``cache`` (``notice`` on stderr first); else FileNotFoundError(``missing``)."""
    for c in candidates:
        if c.is_file():
            return c
    if not allow:
        raise FileNotFoundError(missing)
    print(notice, file=sys.stderr)
    download(url, cache, what=what, hint=hint, sha256=sha256, timeout=timeout)
    return cache


def download(url: str, dest: Path, *, what: str, hint: str, sha256: str | None = None, timeout: float = 60.0) -> None:
    """Fetch ``url`` into ``dest`` through a .part file, checking its ``sha256`` when given; a failure
    leaves nothing and raises FileNotFoundError naming ``what``, the URL, the reason and ``hint``."""
    tmp = dest.with_suffix(".part")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        with urllib.request.urlopen(url, timeout=timeout) as resp, open(tmp, "wb") as fh:
            while chunk := resp.read(1 << 16):
                digest.update(chunk)
                fh.write(chunk)
        if sha256 is not None and digest.hexdigest() != sha256:
            raise ValueError(f"sha256 {digest.hexdigest()[:12]}... is not the release's {sha256[:12]}...")
        tmp.replace(dest)
    except (OSError, ValueError) as exc:  # URLError, HTTPError and timeouts are OSErrors
        tmp.unlink(missing_ok=True)
        reason = getattr(exc, "reason", None) or exc
        raise FileNotFoundError(
            f"{what} not found locally and the download from {url} failed ({reason}); {hint}"
        ) from None
