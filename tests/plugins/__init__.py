"""Small plug-ins registered by the tests from outside the package: a step extension (uniform_push) and a material
model (saint_venant), each one module, as docs/architecture.md and docs/materials.md describe."""
