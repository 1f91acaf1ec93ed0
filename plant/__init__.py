"""The motor: geometry, torque map K(q), current allocation, rigid-body dynamics (MuJoCo model and
CasADi twin), the bottom camera, and the renderers of its view. Imports no other package here."""
