"""Regenerates the tool-written fixtures in this directory.

Needs: pip install gmsh meshio; apt-get install tetgen. Every file is written
by the tool itself; nothing here is hand-edited.
"""
import os
import subprocess

import gmsh
import meshio

here = os.path.dirname(os.path.abspath(__file__))

# Gmsh: a 20 x 30 x 40 mm box, coarse, as MSH 4.1 ASCII and MSH 2.2 binary.
gmsh.initialize(["", "-v", "0"])
gmsh.model.add("box")
gmsh.model.occ.addBox(0, 0, 0, 0.02, 0.03, 0.04)
gmsh.model.occ.synchronize()
gmsh.option.setNumber("Mesh.MeshSizeMax", 0.012)
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.option.setNumber("Mesh.Binary", 0)
gmsh.write(os.path.join(here, "gmsh-box-41.msh"))
gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
gmsh.option.setNumber("Mesh.Binary", 1)
gmsh.write(os.path.join(here, "gmsh-box-22-bin.msh"))
gmsh.finalize()

# meshio: the same mesh as a zlib-compressed .vtu and a binary VTK 5.1 file
# (meshio's defaults).
m = meshio.read(os.path.join(here, "gmsh-box-41.msh"))
m = meshio.Mesh(m.points, [c for c in m.cells if c.type in ("triangle", "tetra")])
meshio.write(os.path.join(here, "meshio-zlib.vtu"), m)
meshio.write(os.path.join(here, "meshio-51-bin.vtk"), m)

# TetGen: the box's surface as a .smesh, meshed with -pq.
smesh = os.path.join(here, "tetgen-block.smesh")
with open(smesh, "w") as f:
    corners = [(x, y, z) for z in (0, 0.04) for y in (0, 0.03) for x in (0, 0.02)]
    f.write("8 3 0 0\n")
    for i, (x, y, z) in enumerate(corners):
        f.write(f"{i + 1} {x} {y} {z}\n")
    quads = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    f.write("6 0\n")
    for q in quads:
        f.write("4 %d %d %d %d\n" % q)
    f.write("0\n0\n")
subprocess.run(["tetgen", "-pqQ", smesh], check=True)
for ext in ("edge", "face"):
    os.remove(os.path.join(here, f"tetgen-block.1.{ext}"))
