"""marlin_aio: an asyncio client for Marlin 3D-printer firmware, with a simulated printer."""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
