"""Sub-commands of the ``dynslam`` CLI, one module each (see ``dynslam_lab/cli.py``)."""
