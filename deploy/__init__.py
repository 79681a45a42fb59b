"""Deployment: Zenoh sessions and the message transport, seals, a secured site's
configuration and the link emulator. The Zenoh configs they start from live in
``zenoh/`` beside this file (installed with the package)."""

from pathlib import Path

ZENOH_CONFIGS = Path(__file__).resolve().parent / "zenoh"
