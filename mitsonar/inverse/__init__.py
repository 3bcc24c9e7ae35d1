"""Inverse problems: scenes refined until their renders match recorded scans (analysis by
synthesis) and fed back into maps. `height_field` (a seabed grid under a side-scan, coarse to fine),
`room` (closed walls seen from inside by a mechanical head), `piles` (piles over a flat seabed
seen by a multibeam), all through `driver` (the checks, the render-and-compare loss and the one
staged-Adam check-then-refine driver)."""
