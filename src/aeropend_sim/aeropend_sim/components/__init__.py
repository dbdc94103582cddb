"""The plant's components and optional effects, one per file (issue 35); see ``docs/model.md``.

``base`` holds the small declaration classes (:class:`~aeropend_sim.components.base.Param`,
:class:`~aeropend_sim.components.base.Term`, :class:`~aeropend_sim.components.base.Component`,
:class:`~aeropend_sim.components.base.Effect`, ...), ``xp`` the array namespaces the physics is
written against, ``registry`` discovers every declaration in the subfolders, ``assembly``
composes the active ones for a rig. This ``__init__`` holds only this docstring.
"""
