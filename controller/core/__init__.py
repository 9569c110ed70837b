"""The pure core: the control law, its data, Ruckig smoothing and small linear algebra; no I/O."""
