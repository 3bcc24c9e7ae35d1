"""The BSDFs ``acoustic`` (`acoustic`, with the presets of `materials`) and ``acoustic_material``
(`acoustic_material`: reflection and backscatter from a material's acoustic properties)."""
