"""The shared base: the interchange format, the robot, kinematics, geometry, the calibration record, settings, the
results protocol, errors, the output folder and the physics of the model. Imported by every stage and command; imports
nothing of the package above it (docs/architecture.md)."""
