"""Planning a reconstruction: the presets, a preset's time and held-out accuracy on a capture
before the run, the time left while it runs, and held-out accuracy tracking. Planning depends
on ``optimize`` (it times and probes the fitting's own steps); ``optimize`` never imports it."""
