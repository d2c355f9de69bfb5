"""Keep API keys out of the server's log.

A WebSocket client in a browser can only send its key as the ``api_key`` query parameter, and
uvicorn writes each request's path with its query string (access log, and the WebSocket's
"accepted" line). The filter rewrites those records' arguments before they are formatted.
"""

from __future__ import annotations

import logging
import re

_KEY_IN_QUERY = re.compile(r"(?i)(api_key=)[^&\s\"']*")
REDACTED = "[redacted]"
LOGGERS = ("uvicorn.access", "uvicorn.error")


def redact(text: str) -> str:
    """``text`` with the value of every ``api_key=`` query parameter replaced."""
    return _KEY_IN_QUERY.sub(r"\1" + REDACTED, text)


class RedactApiKeys(logging.Filter):
    """Removes ``api_key=...`` from a record's message and string arguments."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str) and "api_key=" in record.msg.lower():
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        return True


def redact_api_keys() -> None:
    """Install the filter on uvicorn's loggers (once)."""
    for name in LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactApiKeys) for f in logger.filters):
            logger.addFilter(RedactApiKeys())
