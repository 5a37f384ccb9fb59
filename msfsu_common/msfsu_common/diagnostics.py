"""Small helpers to publish diagnostic_msgs/DiagnosticArray from counters."""

from __future__ import annotations

from collections.abc import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR


def diagnostic_array(stamp, name: str, level: bytes, message: str, values: Mapping[str, object]) -> DiagnosticArray:
    """One-status DiagnosticArray; values are rendered with str() (floats with 3 decimals)."""
    status = DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id="msfsu",
        values=[KeyValue(key=key, value=f"{value:.3f}" if isinstance(value, float) else str(value))
                for key, value in values.items()],
    )
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])

