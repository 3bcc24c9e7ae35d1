"""The one writer of a ``<sensor type="sonar">`` XML element from a dict of plugin parameters
(used by the echo-sounder presets and the dataset configs). Imports nothing from mitsonar."""
from __future__ import annotations

import numbers
from xml.sax.saxutils import quoteattr


def sensor_xml(params, to_world=None, sensor_id="sonar") -> str:
    """A ``<sensor type="sonar" id=sensor_id>`` element: ``to_world`` (16 numbers, row-major, or
    None for none) as a ``<transform>``, then each parameter by its Python type: str -> ``<string>``
    (the value XML-escaped), int (not bool) -> ``<integer>``, anything else -> ``<float>`` written
    with 17 significant digits (a float64 round trip)."""
    items = []
    if to_world is not None:
        matrix = " ".join(f"{float(x):.17g}" for x in to_world)
        items.append(f'<transform name="to_world"><matrix value="{matrix}"/></transform>')
    for k, v in params.items():
        if isinstance(v, str):
            items.append(f'<string name="{k}" value={quoteattr(v)}/>')
        elif isinstance(v, numbers.Integral) and not isinstance(v, bool):
            items.append(f'<integer name="{k}" value="{int(v)}"/>')
        else:
            items.append(f'<float name="{k}" value="{float(v):.17g}"/>')
    return f'<sensor type="sonar" id={quoteattr(sensor_id)}>' + "".join(items) + "</sensor>"
