"""Aeropendulum plant library and simulator: the shared core of aeropend and the simulated plant.

Two halves (docs/architecture.md, "aeropend_sim: the shared core and the simulator"):

* the **shared core** every package builds on, without rclpy: rig files (:func:`load_rig`,
  :class:`Rig`) on the component registry (:func:`families`, :func:`effects`; a component or
  effect is declared with :class:`Param`, :class:`Term`, ...), the plant model
  (:class:`PlantModel`), batch and per-sample simulation (:func:`simulate`,
  :func:`simulate_batch`, :class:`PlantStepper`), recordings (:class:`Recording`), the topic
  contract (``TOPIC_*``, ``TYPE_*``, :class:`Sample`) and the result-folder rule
  (:func:`claim_output_folder`);
* the **simulator**: excitation signals (:func:`aprbs`, :func:`lhs_steps`, ...), the simulated
  plant node's functional core (:mod:`aeropend_sim.sim_core`) and the ROS shell
  (:mod:`aeropend_sim.ros`: the ``sim_node`` and ``excitation`` nodes, the node lifecycle every
  package's nodes use, the process harness). The nodes are not part of this API.

Usage::

    from aeropend_sim import load_rig, simulate, aprbs
    rig = load_rig("thesis_rig")                        # a shipped rig, or a path to a lab's file
    traj = simulate(rig, aprbs(10.0, seed=1).duty)      # duty cycle per 2.048 ms sample
    traj.x[:, 0]                                        # θ [rad]

Names are imported on first use (PEP 562), so ``import aeropend_sim`` costs nothing and the
console scripts start fast; deeper names stay importable from their modules. Submodules import
their siblings directly, never this file (``tools/check_layout.py``). Reference: docs/api.md.
"""

from __future__ import annotations

from aeropend_sim.lazy_api import lazy_api

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    # rig files, the component registry and the plant model
    "aeropend_sim.params": (
        "Rig", "RigFileError", "load_rig", "save_rig", "rig_from_dict", "rig_to_dict", "shipped_rigs",
    ),
    "aeropend_sim.components.registry": (
        "families", "effects", "family", "effect", "family_params", "RegistryError",
    ),
    "aeropend_sim.components.base": ("Param", "Term", "Component", "Family", "Effect", "Diagnosis"),
    "aeropend_sim.model": ("PlantModel", "ModelError"),
    # simulation
    "aeropend_sim.simulation": (
        "simulate", "simulate_batch", "PlantStepper", "Trajectory", "SimulationError", "DEFAULT_BACKEND",
    ),
    # recordings, the topic contract, result folders
    "aeropend_sim.recording": ("Recording", "RecordingError"),
    "aeropend_sim.recording_frame": ("RecordingFrame", "read_recording_frame", "FrameError"),
    "aeropend_sim.contract": (
        "TOPIC_DUTY_CYCLE", "TOPIC_JOINT_STATES", "TOPIC_ARMATURE", "TOPIC_CLOCK", "TOPIC_REFERENCE",
        "TOPIC_EXTRA_CHANNELS", "TYPE_DUTY_CYCLE", "TYPE_JOINT_STATES", "TYPE_ARMATURE", "TYPE_CLOCK",
        "TYPE_REFERENCE", "TYPE_EXTRA_CHANNELS", "namespaced", "Sample", "ContractError", "validate_duty",
    ),
    "aeropend_sim.output_folder": (
        "claim_output_folder", "check_output_file", "OutputFolder", "OutputFolderError",
        "write_file_atomically", "exits_cleanly_on_faults",
    ),
    "aeropend_sim.files.safe_yaml": ("load_yaml", "parse_yaml", "YamlRefusedError"),
    # excitation signals (the simulator's experiments)
    "aeropend_sim.excitation": (
        "ExcitationSignal", "ExcitationError", "make_signal", "step", "staircase", "prbs", "aprbs",
        "density_modulated_prbs", "lhs_steps",
    ),
}
__all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)
