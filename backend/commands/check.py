"""Report, as one JSON object on stdout, whether this interpreter can run the backend
(:func:`backend.variant.readiness`); exit code 1 when it cannot."""

from __future__ import annotations

import json

from ..variant import readiness


def add_arguments(parser):
    parser.add_argument("--variant", help="Mitsuba variant to try (default: automatic)")


def run(args) -> int:
    report = readiness(args.variant)
    print(json.dumps(report))
    return 0 if report["ok"] else 1
