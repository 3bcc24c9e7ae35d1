"""The only two places the comparison uses private helpers of `mitsonar.render`.

Kept here, one small function each, so that a change of those helpers touches this file only.
"""
from __future__ import annotations


def one_line_reason(message) -> str:
    """The user's one-line reason from an error Mitsuba raised (it wraps a failing Python
    plugin constructor's whole traceback): ``mitsonar.render._first_reason``."""
    from ..render import _first_reason

    return _first_reason(str(message))


def scene_sonar(scene):
    """The scene's first ``sonar`` sensor (a `SceneError` naming the scene if it has none):
    ``mitsonar.render._sonar(scene, 0)``."""
    from ..render import _sonar

    return _sonar(scene, 0)
