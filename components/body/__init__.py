"""The body: the pymunk arm plant, the rubber arm and the Pillow camera.

Modules: :mod:`kinematics` (geometry shared by all three), :mod:`plant` (ArmPlant),
:mod:`rubber_arm` (RubberArm), :mod:`camera` (render, Camera).
"""
