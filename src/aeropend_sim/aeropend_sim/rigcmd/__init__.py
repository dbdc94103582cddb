"""The ``rig`` command: ``rig new`` (a rig file to fill in), ``rig fit``, ``rig check``.

See docs/rig_command.md.
"""
