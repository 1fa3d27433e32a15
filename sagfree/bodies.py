"""Rigid bodies strands rest on (``sagfree.bodies.Sphere``, ``Capsule``, ``Mesh``): formulation.bodies."""
from sagfree.formulation.bodies import Body, Capsule, Mesh, Sphere, parse_body

__all__ = ["Body", "Sphere", "Capsule", "Mesh", "parse_body"]
