"""Rendering: Mitsuba 3 / Dr.Jit. The only package that imports drjit or mitsuba; meshes come in as arrays."""
