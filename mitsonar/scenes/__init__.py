"""Scenes beyond the XML files: procedural terrain, a sea surface, echo-sounder presets, the
side-scan demo."""
