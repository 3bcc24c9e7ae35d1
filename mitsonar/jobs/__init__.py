"""Long jobs built on the renderer: integrator comparisons (`compare`) and labelled datasets
(`dataset`)."""
