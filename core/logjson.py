"""``--log-format json``: one JSON object a line, for journald, Loki, Elasticsearch and friends.

Fields: ``time`` (ISO 8601 UTC with milliseconds), ``level``, ``logger``, ``message``,
and ``exception`` (the formatted traceback) when there is one. Extra attributes given
with ``log.info(..., extra={...})`` are added when they are JSON values.
"""

from __future__ import annotations

import json
import logging
from datetime import UTC, datetime

_STANDARD = frozenset(vars(logging.LogRecord("", 0, "", 0, "", (), None))) | {"message", "asctime"}


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        body: dict[str, object] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        for key, value in vars(record).items():
            if (
                key not in _STANDARD
                and key not in body
                and isinstance(value, (str, int, float, bool, type(None)))
            ):
                body[key] = value
        if record.exc_info:
            body["exception"] = self.formatException(record.exc_info)
        elif record.exc_text:
            body["exception"] = record.exc_text
        return json.dumps(body, ensure_ascii=False, default=str)
