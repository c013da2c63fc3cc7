"""The settings schema without torch: each registered component's settings class
(:mod:`.encoders`, :mod:`.models`) and the names of the synthetic tasks (:mod:`.tasks`).

The registries live here, declared with their config classes and the modules that register the
component classes (imported on first use), so the command line, settings files, sweeps and the
docs' flag table are built from one declaration per setting in a fraction of a second.
"""
