"""Programs: ``jara-arm program check`` and ``run`` (``program_command``); whether a program can be
planned on a live arm (``check``) and running it step by step (``run``). The file format is
``schema/program.py``'s; ``Ext/teach`` (the command service) writes its points."""
