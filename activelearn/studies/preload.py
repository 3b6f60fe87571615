"""What the local workers' fork server imports (by name, `studies.processes.QUIET_PRELOAD`): importing
it imports the workers' modules with Ctrl-C ignored."""

from activelearn.studies.processes import preload_quietly

preload_quietly()
