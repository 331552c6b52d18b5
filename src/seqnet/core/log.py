"""The one logger of seqnet (``logging.getLogger("seqnet")``): INFO a few lines per stage, DEBUG with ``-v``."""

from __future__ import annotations

import logging

logger = logging.getLogger("seqnet")
