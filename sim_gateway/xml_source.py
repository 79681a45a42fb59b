"""A SUMO XML file as SUMO itself reads it: plain, or gzipped (``.gz``)."""

from __future__ import annotations

import gzip
from pathlib import Path
from typing import IO


def xml_source(path: str | Path) -> str | IO[bytes]:
    """What ``xml.etree`` can parse for ``path``: the path itself, or the unzipped stream of
    a ``.gz`` file (SUMO reads both; a user's demand often comes zipped)."""
    return gzip.open(path, "rb") if str(path).endswith(".gz") else str(path)
