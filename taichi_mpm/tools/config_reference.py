"""The config reference, docs/config.md, generated from the schema: `python -m taichi_mpm.tools.config_reference > docs/config.md`.

Type, default and allowed values come from walking the pydantic models of config.py; unit and meaning come from
DESCRIPTIONS below (dotted key -> (unit, one line)), kept here so the schema stays short. tests/test_config_reference.py
fails when a schema key has no description, a description names no key, or docs/config.md is stale.
"""
from __future__ import annotations

import sys
import types
import typing
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from .. import config, fields, materials, schemes
from ..io import files as io
from ..bases import registry as bases
from ..schema import OneOf

FACE_NAMES = "x_min, x_max, y_min, y_max, z_min, z_max"
SHAPE_KEYS = "box, sphere, ring, cylinder or mesh"

# dotted key -> (unit, meaning). Units: SI; "1" dimensionless; "" for names, switches and counts.
DESCRIPTIONS: dict[str, tuple[str, str]] = {
    "name": ("", "name of the scene; `{name}` in output.dir; no '/'"),
    "dim": ("", "dimension: 1 (uniaxial strain), 2 (plane strain) or 3"),
    "precision": ("", "floating point of the Taichi fields: f32 (fast) or f64 (verification)"),
    "arch": ("", "Taichi backend; auto picks cuda, else a real GPU's vulkan or metal (dense grid) that can run the scene, else cpu; never a CPU-emulated GPU (docs/contract.md)"),
    "domain": ("", "the background grid: a box [lower, upper] of cells dx"),
    "domain.lower": ("m", "lower corner of the domain, one number per axis"),
    "domain.upper": ("m", "upper corner; upper - lower must be a whole number of cells dx on every axis"),
    "domain.dx": ("m", "grid spacing (the same on every axis)"),
    "domain.sparse": ("", "sparse grid (pointer blocks that follow the particles) or dense"),
    "domain.boundaries": ("", f"wall condition per face: `default` and optionally {FACE_NAMES}"),
    "domain.boundaries.default": ("", "wall of every face not named: a wall type (`slip`) or `{type, friction}`"),
    "domain.boundaries.default.type": ("", "slip: no flow into the wall, may separate; roller: normal velocity "
                                           "zero both ways; sticky: velocity zero; free: no wall; velocity: the "
                                           "face's nodes take `velocity` (a moving wall or driven lid; docs/loads.md)"),
    "domain.boundaries.default.velocity": ("m/s", "velocity wall: per axis a number, an expression of t "
                                                  "(docs/loads.md) or null (that component free); the face itself "
                                                  "stays in place"),
    "domain.boundaries.default.angular_velocity": ("1/s", "velocity wall on a mapped grid's face (domain.map): "
                                                          "the face turns about +z through `center` (a number or "
                                                          "an expression of t): each control point P of the face "
                                                          "gets omega e_z x (P - center) in x and y, plus "
                                                          "`velocity` where given (a turning cylinder or sphere; "
                                                          "docs/isogeometric.md)"),
    "domain.boundaries.default.center": ("m", "the point the turning face's axis (+z) passes through; default the "
                                              "map's center (a nurbs map has none: give it)"),
    "domain.boundaries.default.friction": ("1", "Coulomb friction coefficient mu (slip and roller walls): the "
                                                "tangential velocity drops by mu times the normal velocity removed"),
    **{f"domain.boundaries.{f}": ("", f"wall at the {'lower' if f.endswith('min') else 'upper'} {f[0]} face; null "
                                      "takes `default`") for f in FACE_NAMES.split(", ")},
    "domain.knots": ("", "knot vectors per axis for the B-spline bases (docs/isogeometric.md); an axis left out "
                         "keeps the uniform open knot vector of dx"),
    **{f"domain.knots.{a}": ("m", f"open knot vector along {a}: nondecreasing, domain.lower and domain.upper each "
                                  "p + 1 times (p: 1, 2, 3 for linear, quadratic, cubic), interior knots at most p "
                                  "times (multiplicity k leaves the basis C^(p-k)); the CFL step follows the "
                                  "shortest span") for a in "xyz"},
    "domain.map": ("", "a curvilinear (mapped) grid, 2D (annulus, nurbs) or 3D (cylinder, shell), solver.basis "
                       "quadratic (docs/isogeometric.md); "
                       "domain.lower/upper must hold it and domain.dx sets the particle spacing only"),
    "domain.map.type": ("", "annulus: exact circles through NURBS weights; faces x_min/x_max are the straight "
                            "edges at angle 0 and `angle` (none for a full ring), y_min/y_max the inner and outer "
                            "circles. nurbs: a quadratic NURBS patch given as knots, control points and weights; "
                            "faces x_min/x_max are the first and last row of control points, y_min/y_max the first "
                            "and last column. cylinder (3D): a thick-walled cylinder about an axis along +z; x_min/"
                            "x_max the flat ends of a sector, y_min/y_max the inner and outer cylinders, z_min/z_max "
                            "the flat ends. shell (3D): a spherical shell between two latitudes; x_min/x_max the "
                            "meridian planes of a sector, y_min/y_max the inner and outer spheres, z_min/z_max the "
                            "cones at the lower and upper latitude"),
    "domain.map.knots": ("", "the patch's open quadratic knot vectors, two in 2D, three in 3D (each end 3 times, interior knots at most "
                             "twice); any parameter scale: they are scaled so that a span is a cell"),
    "domain.map.knots.x": ("", "knots of the first parameter (the rows of control_points)"),
    "domain.map.knots.y": ("", "knots of the second parameter (the points within a row)"),
    "domain.map.knots.z": ("", "3D: knots of the third parameter (the points within a column: control_points[i][j])"),
    "domain.map.patches": ("", "instead of knots / control_points / weights: several patches joined in order along "
                               "x, each one's last layer of control points and weights equal to the next one's "
                               "first (stored once: a C0 joint); their knots along y (and z) must be equal in cells "
                               "(conforming patches)"),
    "domain.map.patches[].knots": ("", "the patch's knot vectors x, y (z), as domain.map.knots"),
    "domain.map.patches[].control_points": ("m", "the patch's control points, as domain.map.control_points"),
    "domain.map.patches[].weights": ("1", "the patch's weights, as domain.map.weights; null: all 1"),
    "domain.map.control_points": ("m", "control_points[i][j] = [x, y] (3D: [i][j][k] = [x, y, z]): len(knots.x) - "
                                       "3 rows of len(knots.y) - 3 points (of len(knots.z) - 3); the map must not "
                                       "fold (det J of one sign, checked at 5 points per cell and axis, up to 64 "
                                       "cells per axis in 2D, 16 in 3D) and must lie inside domain.lower/upper; "
                                       "bodies must lie inside the map"),
    "domain.map.weights": ("1", "one positive weight per control point, same layout; null: all 1 (a B-spline map)"),
    "domain.map.refine": ("", "[cells per knot span along x, along y]: each nonzero knot span is split evenly by "
                              "knot insertion (the geometry stays exactly the same; give the coarse exact shape, "
                              "refine for the grid); the refined net's size is estimated from the knots and "
                              "checked against limits.memory_gb before anything is built (docs/reliability.md)"),
    "domain.map.periodic": ("", "the first parameter wraps around (a full ring): the last row of control points "
                                "and weights must equal the first, and there are no x_min/x_max faces"),
    "domain.map.inner_radius": ("m", "radius of the inner circle, cylinder or sphere"),
    "domain.map.outer_radius": ("m", "radius of the outer circle, cylinder or sphere"),
    "domain.map.angle": ("deg", "angular span counter-clockwise from +x (about +z in 3D); 360: a full turn, periodic "
                                "in the angle"),
    "domain.map.center": ("m", "centre of the circles (annulus, shell); cylinder: the axis' point at its base"),
    "domain.map.cells": ("", "[cells along the angle, cells across the radius] (annulus); 3D: and cells along the "
                             "axis (cylinder) or the latitude (shell); each arc's cells a multiple of the number "
                             "of quarter turns (rational pieces) it spans; sized against limits.memory_gb before "
                             "anything is built (docs/reliability.md)"),
    "domain.map.length": ("m", "cylinder: its length along +z from `center`"),
    "domain.map.latitudes": ("deg", "shell: [lower, upper] latitude, inside (-90, 90) (the poles are left out: "
                                    "det J = 0 there)"),
    "solver": ("", "time integration and the MPM scheme"),
    "solver.basis": ("", "shape functions (docs/bases.md): " + "; ".join(
        f"{n}: {bases.get(n).description}" for n in bases.names())),
    "solver.cpdi": ("", "options of basis cpdi"),
    "solver.ddmp": ("", "options of basis ddmp"),
    "solver.ddmp.fold_below": ("1", "a node whose dual domain is filled below this fraction (a free surface, material "
                                    "entering a cell) shares 1 - fill / fold_below of its force with its fullest "
                                    "neighbour, the pair taking one acceleration along the axes its walls leave free "
                                    "(docs/bases.md, \"DDMP's small nodes\"); 0: off. Off with grips, multi-field "
                                    "contact and xpic"),
    "solver.ddmp.sub_points": ("", "each particle's weights and gradient (mass, momentum, force, F) averaged over "
                                   "two sub-points per axis, the centres of the halves of its domain stretched by "
                                   "|F_aa| (Dhakal & Zhang 2016's sub-points): second-order convergence with 2 "
                                   "particles per cell where one point per particle stalls, at 1.5x the step in 2D "
                                   "and 2.2x in 3D (a stencil of 5 nodes per axis instead of 4; docs/bases.md, "
                                   "\"DDMP's sub-points\")"),
    "solver.cpdi.variant": ("", "cpdi1: parallelogram / parallelepiped domains with half-edges F r0 (Sadeghirad et "
                                "al. 2011); cpdi2: quadrilateral / hexahedral domains whose corners move with the "
                                "grid (Sadeghirad et al. 2013; not with a crack section or asflip)"),
    "solver.transfer": ("", "particle-grid velocity transfer (docs/transfers.md): " + "; ".join(
        f"{s.name}: {s.summary}" + (f" (bases {', '.join(schemes.bases_for(s.name))})" if s.basis_need else "")
        for s in schemes.SCHEMES.values())),
    "solver.update": ("", "usl (update stress last), musl (F from re-mapped velocities, Sulsky 1995) or usf "
                          "(update stress first: F and the stress from the velocities before forces, Bardenhagen "
                          "2002; docs/transfers.md)"),
    "solver.xpic_order": ("1", "XPIC's order m when transfer is xpic: 1 is PIC, each order one more particle-grid "
                              "pass and less numerical dissipation (Hammerquist & Nairn 2017; docs/transfers.md)"),
    "solver.polypic_modes": ("", "PolyPIC's modes when transfer is polypic: total (the products of total degree <= "
                                 "the basis' degree: 6 in 2D, 10 in 3D for quadratic) or full (every product of "
                                 "per-axis degree <= it: 9 and 27; the fit interpolates the stencil; 1.5x total's step "
                                 "in 3D: docs/transfers.md) (Fu et al. 2017)"),
    "solver.asflip": ("", "ASFLIP's parameters when transfer is asflip (Fei et al. 2021; docs/transfers.md)"),
    "solver.asflip.flip": ("1", "ASFLIP's FLIP part: v = v_PIC + flip (v_p - sum w v_old)"),
    "solver.asflip.position": ("1", "ASFLIP's position correction for particles not compressed (J >= 1): x += dt "
                                    "(v_PIC + position (v_new - v_PIC))"),
    "solver.asflip.position_min": ("1", "ASFLIP's position correction for compressed particles (J < 1)"),
    "solver.flip_blend": ("1", "FLIP fraction of the velocity update when transfer is flip (1: pure FLIP)"),
    "solver.gimp_domain": ("", "GIMP particle half-width: uniform (fixed) or deforming (stretched with F_aa only; "
                               "superseded by basis cpdi, which follows the full F)"),
    "solver.quadrature": ("", "particle quadrature of the B-spline bases (linear, quadratic, cubic): point (weights "
                              "and gradients at the particle) or domain (the particle's knot span averaged over "
                              "its domain of the initial spacing; cubic keeps second order at sticky walls with 2 "
                              "particles per cell, docs/accuracy.md)"),
    "solver.stress_difference": ("", "the nodal force from each particle's stress minus the average stress at the "
                                     "node (the local stress difference of Perez, Barclay & Zhang 2023): inside a "
                                     "body the particles' quadrature error under a uniform stress vanishes and the "
                                     "1D convergence of every tensor-product basis rises to about second order at "
                                     "2 particles per cell; linear momentum is then kept only approximately "
                                     "(docs/accuracy.md, \"The local stress difference\")"),
    "solver.cfl": ("1", "adaptive time step: the smallest of cfl dx / (wave speed + max speed), cfl sqrt(dx / max "
                        "acceleration) for gravity and body forces, cfl rho dx^2 / (2 d mu) for viscosity. Smaller "
                        "is not always closer: each step's transfers smooth the velocity across shear bands, so "
                        "granular flows run shorter at a smaller cfl (docs/materials.md, \"Why the low columns' "
                        "run-out moves with dx\"); refine dx at one cfl"),
    "solver.dt": ("s", "fixed time step instead of the CFL rule; null: adaptive"),
    "solver.end_time": ("s", "simulated time to run to"),
    "solver.gravity": ("m/s^2", "gravitational acceleration, one number per axis; null: none"),
    "solver.max_steps": ("", "stop after this many steps; null: no limit"),
    "solver.unroll": ("", "unroll the stencil loop (true / false); auto unrolls only runs of at least 1e7 "
                          "particle-steps (particles x steps to end_time at the starting dt; shorter runs keep the "
                          "loop at run time and start sooner), then stencils of at most 16 nodes whole and the "
                          "trailing axes of larger tensor-product ones, up to 9 nodes per run-time iteration (3D "
                          "gimp and quadratic: 9 of 27, cubic and ddmp: 4 of 64)"),
    "solver.scatter": ("", "how P2G adds particle values to the grid: coloured bins the particles by grid block each "
                           "step and lets the blocks of one of 2^d colours add in parallel without atomics (same "
                           "result, 2-3x faster P2G on CPUs; tensor-product bases only); atomic adds atomically; "
                           "auto: coloured on a CPU where the basis allows and the scene is large enough to gain (2D from "
                           "2 300 particles, 3D from 440; any size when deterministic), atomic on GPUs, in smaller "
                           "scenes, with cpdi and on a domain.map"),
    "solver.energy_growth_limit": ("1", "stop with an instability when total energy exceeds its initial value + "
                                        "body-force work - viscous dissipation by more than this fraction of the "
                                        "largest kinetic + strain energy (checked every few steps and after every "
                                        "advance); null: off"),
    "solver.volumetric": ("", "standard (each particle's own J) or fbar (the step's volume change averaged over the "
                              "grid, against volumetric locking of nearly incompressible materials)"),
    "solver.deterministic": ("", "bit-identical runs regardless of thread count and load (CPU: no fast math, and one "
                                 "thread unless every sum of the scene has one order on any threads: coloured "
                                 "scatter without ddmp, fbar, crack, loads, grips, velocity walls, wall probes, "
                                 "viscosity or plasticity); GPUs: float atomics stay unordered"),
    "contact": ("", "contact between bodies by a method of its own (docs/contact.md); absent or null: off, nothing "
                    "allocated; not with a crack section"),
    "contact.method": ("", "multi_field: one velocity field per body or group (Bardenhagen et al. 2000)"),
    "contact.friction": ("1", "Coulomb coefficient between the fields (>= 0), but the friction_pairs' own"),
    "contact.friction_pairs": ("", "pairs of bodies in different fields with a Coulomb coefficient of their own "
                                   "(with contact.bodies groups: the two bodies' fields')"),
    "contact.bodies": ("", "groups of bodies (names or indices) sharing one field; a body in no group gets its own; "
                           "null: every body its own field"),
    "crack": ("", "crack finder (damage gradients, opposite-side flags); absent or null: off, nothing compiled"),
    "crack.threshold": ("1", "epsilon_thresh: a node is across the crack from a particle when n_p . n_node < -threshold"),
    "crack.kernel_radius": ("1", "SPH support radius, in initial particle spacings"),
    "crack.contact_in_compression": ("", "keep a node across the crack while the normal stress is compressive"),
    "crack.damage_threshold": ("1", "damage D at or above which a particle is near a discontinuity"),
    "crack.gradient_threshold": ("1", "|grad D| r (r: the SPH radius) at or above which a particle is near a "
                                      "discontinuity"),
    "crack.normal_refresh": ("1", "particle normals (the SPH damage gradients) are kept between steps; once a "
                                  "particle has moved half this fraction of the SPH radius, those whose "
                                  "neighbours moved against each other by that much are recomputed (all if a "
                                  "damage value changed); 0: recomputed every step"),
    "crack.friction": ("1", "Coulomb friction coefficient mu across crack faces and body interfaces in "
                            "contact: each node near a contact gets a second velocity field (the particles in "
                            "contact across it), and the two fields' tangential slip loses mu times their normal "
                            "approach, never beyond sticking; 0: frictionless (the seed's method); not with "
                            "solver.update musl"),
    "crack.friction_pairs": ("", "pairs of interface bodies with a Coulomb coefficient of their own instead of "
                                 "crack.friction (the node's owner body and its second field's)"),
    "crack.friction_pairs[].bodies": ("", "the two bodies (names or indices; under crack, interface bodies)"),
    "crack.friction_pairs[].mu": ("1", "their Coulomb coefficient (>= 0)"),
    "crack.contact_gap": ("1", "between interface bodies, a particle is in contact only while the nearest particle "
                               "facing it lies within (1 + contact_gap) particle spacings (their domains at most "
                               "contact_gap spacings apart); null: anywhere within the SPH support (the seed's "
                               "method)"),
    "materials": ("", "named materials; bodies refer to them by name"),
    "materials.<name>": ("", "one material"),
    # materials.<name>.*: from the models' schemas (taichi_mpm/materials/), added below DESCRIPTIONS
    "bodies": ("", "the bodies, at least one; particles fill each shape"),
    "bodies[].name": ("", "label of the body for the reader (bodies are numbered in list order); null: unnamed"),
    "bodies[].shape": ("", f"region filled with particles: {SHAPE_KEYS}, chosen by `type`"),
    "bodies[].shape.type": ("", "box {lower, upper}, sphere {center, radius} (a disk in 2D, a segment in 1D), "
                                "ring {center, inner_radius, outer_radius}, cylinder (3D), mesh {file}"),
    "bodies[].shape.lower": ("m", "lower corner of the box"),
    "bodies[].shape.upper": ("m", "upper corner of the box"),
    "bodies[].shape.rotation": ("deg", "rotation about the centre: a scalar in 2D, Euler angles [rx, ry, rz] in 3D"),
    "bodies[].shape.center": ("m", "centre point"),
    "bodies[].shape.radius": ("m", "radius"),
    "bodies[].shape.inner_radius": ("m", "inner radius of the ring (0: a full disk or ball) or of the cylinder "
                                         "(> 0: a tube)"),
    "bodies[].shape.outer_radius": ("m", "outer radius of the ring"),
    "bodies[].shape.height": ("m", "length of the cylinder along its axis"),
    "bodies[].shape.axis": ("", "axis of the cylinder"),
    "bodies[].shape.file": ("", "a closed surface or volume mesh meshio reads; relative to the config file"),
    "bodies[].shape.scale": ("1", "scale factor of the mesh coordinates: one number or one per axis"),
    "bodies[].shape.translate": ("m", "shift of the mesh after scaling; null: none"),
    "bodies[].material": ("", "name of a material in `materials`"),
    "bodies[].particles_per_cell": ("", "particles per cell along each axis"),
    "bodies[].placement": ("", "regular grid of particles, jittered (each moved randomly by up to a quarter "
                               "spacing per axis), or map (domain.map only: particles_per_cell per axis in every "
                               "cell of the map's parameter space, volumes |det J| dxi^d, so the body's faces follow "
                               "the map's curved ones; tractions' faces then name the map's parameter faces; "
                               "docs/isogeometric.md)"),
    "bodies[].velocity": ("m/s", "initial velocity, per axis a number or an expression of x, y, z such as "
                                 "\"0.1 * sin(pi * x / 25)\" (docs/loads.md); null: at rest"),
    "bodies[].stress": ("Pa", "initial Cauchy stress (tension positive), a number or expression of x, y, z per "
                              "component: Voigt [sxx] (1D), [sxx, syy, sxy] (2D), [sxx, syy, szz, syz, sxz, sxy] (3D), "
                              "or a symmetric d x d matrix; kept as a stored stress added to the material's "
                              "(docs/loads.md); null: none"),
    "bodies[].tractions": ("", "prescribed surface tractions or pressures: forces on the body's exposed particle "
                               "faces (docs/loads.md)"),
    "bodies[].tractions[].region": ("", "box or sphere: the surface particles inside it are loaded; null: the "
                                        "whole surface"),
    "bodies[].tractions[].faces": ("", "outward normals of the particle faces loaded (x_min ... z_max; with "
                                       "placement map the map's parameter faces, loaded along their exact area "
                                       "vectors); null: every exposed face in the region (a corner's faces on both "
                                       "sides)"),
    "bodies[].tractions[].traction": ("Pa", "traction vector, one number per axis (give it or `pressure`)"),
    "bodies[].tractions[].pressure": ("Pa", "normal pressure, positive pushing inward (give it or `traction`)"),
    "bodies[].tractions[].ramp": ("1", "factor on the load, a number or an expression of t such as "
                                       "\"min(t / 0.01, 1)\""),
    "bodies[].tractions[].apply_to": ("", "particles: forces on the loaded particles, spread by their weights; "
                                          "nodes (placement: map only, no crack or contact section): the faces' "
                                          "consistent nodal load int R_i t dA on the mapped grid's control points, "
                                          "fixed where the faces start (docs/loads.md)"),
    "bodies[].prescribed_velocity": ("", "grips: body regions whose velocity is prescribed on the grid nodes "
                                         "their particles touch (docs/loads.md); the reaction: "
                                         "Simulation.prescribed_impulse()"),
    "bodies[].prescribed_velocity[].region": ("", "box or sphere: the body's particles inside it at t = 0; null: "
                                                  "the whole body"),
    "bodies[].prescribed_velocity[].velocity": ("m/s", "per axis a number, an expression of t, or null (that "
                                                       "component free)"),
    "bodies[].angular_velocity": ("rad/s", "initial rotation about the shape's centre, added to velocity: a scalar "
                                           "in 2D, a vector in 3D; null: none"),
    "bodies[].interface": ("", "flag the surface particles for multi-body interaction (crack finder; a face on "
                                "the domain's boundary is no surface)"),
    "bodies[].damage_regions": ("", "pre-cracks and notches: regions whose particles start damaged"),
    "bodies[].damage_regions[].shape": ("", "the region (a shape like bodies[].shape)"),
    "bodies[].damage_regions[].value": ("1", "initial damage of the particles inside"),
    "bodies[].overlap": ("", "particles of this body inside an earlier body: error (refuse), skip (leave them out) "
                             "or allow (keep both, doubling the mass there)"),
    "bodies[].geostatic": ("", "cam_clay bodies: start consolidated under the body's own weight (K0 conditions): "
                               "vertical effective stress rho |g| (surface - height) along the last axis (gravity "
                               "must point down it), k0 times it across, the yield surface through it (docs/"
                               "materials.md); null: the material's initial_pressure everywhere"),
    "bodies[].geostatic.k0": ("1", "horizontal over vertical effective stress (Jaky: 1 - sin phi)"),
    "bodies[].geostatic.ocr": ("1", "overconsolidation: p_c over the p_c of the yield surface through the stress "
                                    "(1: normally consolidated)"),
    "bodies[].geostatic.surface": ("m", "height of the ground surface the depth is measured from; null: the "
                                        "top of the body's shape"),
    "limits": ("", "resource limits checked before anything is allocated"),
    "limits.memory_gb": ("GB", "largest estimated memory of a run; null: half of this machine's physical memory"),
    "limits.particles": ("", "largest particle count; null: only the memory limit"),
    "limits.steps": ("", "largest estimated number of steps to solver.end_time (dt from every rate of the CFL rule "
                         "at t = 0); null: 1e8"),
    "limits.allow_large": ("", "run past the limits (memory, particles, steps; the estimate still prints); same as "
                               "--allow-large"),
    "output": ("", "what a run writes into its folder"),
    "output.dir": ("", "run folder; {name} is replaced by the scene name"),
    "output.every": ("s", "simulated time between outputs"),
    "output.formats": ("", "vtu and npz snapshots, png frames, mp4 or gif movie"),
    "output.fields": ("", "particle fields written to each snapshot besides the standard set (see Output fields "
                          "below; with output.only_fields, the only ones)"),
    "output.only_fields": ("", "true: a VTU holds the positions and exactly output.fields; false: also the standard "
                               "set (velocity, stress, von_mises, J, body, damage and material states when present)"),
    "output.checkpoint_every": ("outputs", "checkpoint.npz is rewritten every this many outputs, at the first and "
                                           "the last, on a stop (Ctrl-C, SIGTERM) and after a numerical failure "
                                           "(the last output's state); 1: at every output"),
    "output.writer": ("", "thread: snapshots, checkpoints, probe rows and frame records are written by a background "
                          "thread while the solver steps (a queue of 8 jobs, about 3 outputs; the solver waits only when it is full); "
                          "inline: by the solver's thread, as before. The same files either way"),
    "output.render": ("", "off-screen frames"),
    "output.render.color_by": ("", "colour field: speed, von_mises, J, body, damage, pressure, plastic_strain, Jp, "
                                   "vx, vy, vz, or a stress component sxx, syy, szz, sxy, ... (any scalar of Output "
                                   "fields below)"),
    "output.render.size": ("px", "[width, height] of a frame"),
    "output.render.camera": ("", "3D view: iso, xy, xz, yz, front, side, top (1D and 2D are always seen along z)"),
    "output.render.point_size": ("px", "particle size on screen; null: from the particle spacing"),
    "output.render.colormap": ("", "matplotlib colormap name"),
    "output.render.clim": ("unit of the field", "fixed colour limits [min, max]; null: robust limits from the "
                           "percentiles of the whole run's values, fixed across its frames"),
    "output.render.framing": ("m", "what the 3D camera frames: run, the bodies over the whole run (known at its end); "
                              "domain; or a box [[x, y, z], [x, y, z]] (lower, upper). With domain or a box and a "
                              "colour range fixed in advance (clim, or a label field such as body) each frame is "
                              "drawn while the solver steps, else at the end of the run; 2D and 1D frames always "
                              "show the domain (clim alone is enough there)"),
    "output.render.scale": ("", "colour scale: linear, or log (for stresses spanning decades; values at or below "
                                "the low limit take the bottom colour)"),
    "output.render.percentiles": ("%", "[low, high] percentiles of all particles over all frames that set the colour "
                                       "range when clim is null (magnitudes such as speed and von_mises start at 0 "
                                       "on a linear scale; a log range spans at most 4 decades)"),
    "output.probes": ("", "quantities over time, one CSV per probe in probes/NAME.csv (see Probes below)"),
    "output.probes[].name": ("", "the probe's name, also its file probes/NAME.csv: letters, digits, _ and -; unique"),
    "output.probes[].type": ("", "point: one particle; body: a body's means; region: the means over the particles "
                                 "inside a shape at t = 0; wall: the reaction force of a domain face; contact: the force the "
                                 "other bodies exert on a body; grip: the force of a prescribed-velocity region"),
    "output.probes[].point": ("m", "point probe: the particle nearest this point at t = 0 is followed"),
    "output.probes[].body": ("", "body and contact probes: the body's name (bodies[].name) or index (from 0)"),
    "output.probes[].region": ("", "region probe: a box or sphere; the particles inside it at t = 0"),
    "output.probes[].face": ("", "wall probe: the domain face whose force on the material is recorded"),
    "output.probes[].grip": ("", "grip probe: a bodies[].prescribed_velocity entry, numbered from 0 over all bodies "
                                 "in order; its force on the material is recorded"),
    "output.probe_every": ("s", "time between probe samples (taken at the first step on or after each multiple); "
                                "step: after every step; null: at every output. t = 0 is always sampled"),
}

DESCRIPTIONS.update(materials.key_descriptions())  # each model's keys: unit and meaning from its schema

PROBES_DOC = """\
Each probe writes `probes/NAME.csv` in the run folder: a header row of `column [unit]` names, then one row per
sample, starting with `time [s]` and `step`. Vectors have one column per axis (`x`, `y`, `z` up to dim); the
stress columns are the Cauchy stress (tension positive) of the full 3x3 tensor: the normal components `sxx`,
`syy`, `szz` always (plane strain and uniaxial strain have out-of-plane stress), the shear components between
the axes that exist (`sxy` in 2D; `sxy`, `sxz`, `syz` in 3D). In 2D forces and energies are per metre of depth
(`N/m`, `J/m`), in 1D per m^2 of cross-section.

| type | columns | meaning |
| --- | --- | --- |
| `point` | `x.. [m]`, `ux.. [m]`, `vx.. [m/s]`, stress `[Pa]` | the particle nearest `point` at t = 0 (the lowest index on a tie): position, displacement from t = 0, velocity, stress |
| `body`, `region` | `ux.. [m]`, `vx.. [m/s]`, stress `[Pa]`, `kinetic [J]` | over the body's particles, or those inside `region` at t = 0: mass-weighted mean displacement and velocity (the centre of mass), volume-weighted mean stress over the current volumes, kinetic energy sum m v^2 / 2 (without APIC's affine part) |
| `grip` | `fx.. [N]` | the force a `bodies[].prescribed_velocity` entry (`grip`: its number over all bodies, from 0) exerts on the material, measured like a wall's: the momentum its prescribed velocity adds at the nodes it holds, per interval; nan in the t = 0 row |
| `wall` | `fx.. [N]` | the force the face exerts on the material: the momentum its wall condition adds at the face's grid nodes, summed over the steps since the previous sample and divided by the time they cover, from the previous sample's `velocity_time` to this one's (leapfrog velocities lag the clock by half a step; a mean, not one step); nan in the t = 0 row. A corner node gives each face the change of that face's own condition. Not available with a crack section |
| `contact` | `fx.. [N]` | the force the other bodies exert on `body` (contact through the shared grid): the change of the body's momentum since the previous sample divided by the time between the samples' `velocity_time`, minus its weight (mass x `solver.gravity`); nan in the t = 0 row. It is the contact force only while the body touches no wall and has no `body_force` (those would be included) |

The particles a probe follows are chosen from the positions at t = 0, so a resumed run follows the same ones;
`--resume` keeps the rows up to the checkpoint's time. Rows are flushed as they are written, so after a stop or a
numerical failure the files hold every sample taken. `taichi-mpm plot RUN_DIR` draws them."""

# diagnostics.csv: one row per output; 2D and 3D have the angular momentum, momentum has one column per axis
DIAGNOSTICS: dict[str, tuple[str, str]] = {
    "time": ("s", "simulated time of the row"),
    "step": ("", "steps taken so far"),
    "dt": ("s", "time step in force at this time (CFL rule or fixed dt), not the last shortened step"),
    "kinetic": ("J", "kinetic energy sum 1/2 m v^2 (velocities at `velocity_time`, half a step before the row time)"),
    "strain": ("J", "strain energy sum V0 psi(F)"),
    "gravity": ("J", "gravitational potential energy -sum m g . x (zero at the origin)"),
    "total": ("J", "kinetic + strain + gravity"),
    "momentum_x": ("kg m/s", "linear momentum along x (also _y, _z up to dim)"),
    "angular_momentum_x": ("kg m^2/s", "angular momentum about the origin, APIC's affine part included "
                                       "(also _y, _z; 2D and 3D)"),
    "max_speed": ("m/s", "largest particle speed"),
    "cfl": ("1", "dt (wave speed + max speed) / dx"),
}

CONVENTIONS = """\
Conventions, once for every key and file:

- Units are SI (m, s, kg, Pa, J); angles in degrees unless stated.
- 2D is plane strain: nothing moves or stretches along z (F_zz = 1), so sigma_zz is not zero; lengths per axis are
  m, a particle's volume is an area (m^2 per metre of depth) and masses, energies and momenta are per metre of depth.
- 1D is uniaxial strain: the lateral axes are held (F_yy = F_zz = 1), so the lateral stress sigma_yy = sigma_zz is
  not zero; volumes, masses and energies are per m^2 of cross-section.
- Stress is the Cauchy stress, tension positive; pressure is -tr(sigma) / 3, compression positive.
- Unknown keys are errors. Overrides use dotted keys: `--set solver.basis=cubic`, `--set bodies.0.velocity=[0,-2,0]`.
- In the tables, `<name>` is any material name, `[]` any list item; `required` marks keys without a default.
"""


# ---------------------------------------------------------------- walking the schema
def _strip(tp):
    """(bare type, constraints) of an annotation: Annotated metadata gathered into a list."""
    cons = []
    while typing.get_origin(tp) is Annotated:
        tp, *meta = typing.get_args(tp)
        for m in meta:
            cons.extend(getattr(m, "metadata", None) or [m])
    return tp, cons


def _constraints(cons) -> list[str]:
    out = []
    for c in cons:
        if isinstance(c, OneOf):   # a registry's names (solver.basis: bases/registry.py)
            out.append(" \\| ".join(map(str, c.values())))
        for attr, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="), ("min_length", "at least")):
            v = getattr(c, attr, None)
            if v is not None:
                out.append(f"{op} {v}" + (" items" if attr == "min_length" else ""))
    return out


def _union_args(tp):
    if typing.get_origin(tp) in (Union, types.UnionType):
        return list(typing.get_args(tp))
    return None


def _is_model(tp) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _describe_type(tp) -> tuple[str, list[str]]:
    """(type text, allowed-value notes) of an annotation without None."""
    tp, cons = _strip(tp)
    allowed = _constraints(cons)
    args = _union_args(tp)
    if args is not None:
        if all(_is_model(_strip(a)[0]) for a in args):
            return "mapping", allowed
        parts = [_describe_type(a) for a in args]
        texts = [t for t, _ in parts]
        if "bool" in texts and any(typing.get_origin(a) is Literal for a in args):
            lits = [v for a in args if typing.get_origin(a) is Literal for v in typing.get_args(a)]
            return "string or bool", [" \\| ".join(map(str, lits)) + " \\| true \\| false"]
        for _, al in parts:
            allowed += [x for x in al if x not in allowed]
        return " or ".join(dict.fromkeys(texts)), allowed
    if typing.get_origin(tp) is Literal:
        vals = typing.get_args(tp)
        kind = "int" if all(isinstance(v, int) for v in vals) else "string"
        return kind, [" \\| ".join(map(str, vals))]
    if typing.get_origin(tp) is list:
        inner, al = _describe_type(typing.get_args(tp)[0])
        return "list of " + {"number": "numbers", "string": "strings", "int": "ints"}.get(inner, inner), allowed + al
    if typing.get_origin(tp) is dict:
        return "mapping of name to " + _describe_type(typing.get_args(tp)[1])[0], allowed
    if _is_model(tp):
        short = getattr(tp, "__shorthand__", None)
        return (f"string or mapping (a string s means {{{short}: s}})" if short else "mapping"), allowed
    return {float: "number", int: "int", bool: "bool", str: "string", type(None): "null"}.get(
        tp, getattr(tp, "__name__", str(tp))), allowed


def _default_text(field) -> str:
    if field.default is PydanticUndefined and field.default_factory is None:
        return "required"
    value = field.default_factory() if field.default is PydanticUndefined else field.default
    if isinstance(value, BaseModel):
        if not getattr(type(value), "__shorthand__", None):
            return ""  # a section: its keys have their own defaults
        value = value.model_dump(mode="json")
    return _yaml(value)


def _yaml(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_yaml(v)}" for k, v in value.items()) + "}"
    return str(value)


def _without_none(tp):
    args = _union_args(tp)
    if args is None or type(None) not in args:
        return tp, False
    rest = [a for a in args if a is not type(None)]
    return (rest[0] if len(rest) == 1 else Union[tuple(rest)]), True


def _child(tp, key):
    """What a key holds inside: (a model or the variant models of a discriminated union, prefix of its keys, the
    key of a row for one entry of a mapping of names) or None."""
    tp = _strip(tp)[0]
    head = None
    if typing.get_origin(tp) is list:
        tp, key = _strip(typing.get_args(tp)[0])[0], key + "[]"
    elif typing.get_origin(tp) is dict:
        tp, key = _strip(typing.get_args(tp)[1])[0], key + ".<name>"
        head = key
    if _is_model(tp):
        return tp, key, head
    args = _union_args(tp)
    if args and all(_is_model(_strip(a)[0]) for a in args):
        return [_strip(a)[0] for a in args], key, head
    return None


def walk(model=config.Config, prefix: str = "", seen: dict | None = None):
    """Rows (dotted key, type, default, allowed values, note) of every key under `model`, depth first. A model reached
    again (the wall form on every face, the shapes of damage regions) is referred to, not repeated."""
    seen = {} if seen is None else seen
    for name, field in model.model_fields.items():
        key = prefix + name
        tp, cons = _strip(field.annotation)
        tp, nullable = _without_none(tp)
        text, allowed = _describe_type(tp)
        allowed = _constraints(cons + list(field.metadata)) + allowed
        child = _child(tp, key)
        ident = None if child is None else (tuple(child[0]) if isinstance(child[0], list) else child[0])
        note = ""
        if child is not None and ident in seen:
            note, child = f"same keys as `{seen[ident]}`", None
        yield key, text + (" or null" if nullable else ""), _default_text(field), " ; ".join(allowed), note
        if child is None:
            continue
        inner, child_key, head = child
        seen[ident] = child_key
        if head:
            yield head, "mapping", "", "", ""
        if isinstance(inner, list):
            yield from _walk_variants(inner, child_key + ".", seen)
        else:
            yield from walk(inner, child_key + ".", seen)


def _tag_field(variants) -> str:
    """The discriminator: the field every variant fixes to one literal value (`type` for shapes)."""
    for name in variants[0].model_fields:
        if all(name in v.model_fields and typing.get_origin(v.model_fields[name].annotation) is Literal
               and len(typing.get_args(v.model_fields[name].annotation)) == 1 for v in variants):
            return name
    raise TypeError(f"no discriminator field in {[v.__name__ for v in variants]}")


def _walk_variants(variants, prefix, seen):
    """Keys of a discriminated union (the shapes), each key once, noting the variants that have it."""
    tag = _tag_field(variants)
    tags = [typing.get_args(v.model_fields[tag].annotation)[0] for v in variants]
    rows: dict[str, list] = {prefix + tag: [(prefix + tag, "string", "required", " \\| ".join(tags), ""), {}]}
    for v, t in zip(variants, tags):
        for row in walk(v, prefix, seen):
            if row[0] != prefix + tag:
                rows.setdefault(row[0], [row, {}])[1][t] = row[2]
    for row, have in rows.values():
        default = row[2]
        if len(set(have.values())) > 1:  # the variants differ: name each one's default
            default = "; ".join(f"{d} ({t})" for t, d in have.items())
        every = len(have) == len(tags)  # a key of every variant (a material's density) needs no list of them
        yield (row[0], row[1], default, row[3], "" if every else ", ".join(have) if have else row[4])


def keys() -> list[str]:
    return [row[0] for row in walk()]


# ---------------------------------------------------------------- the document
def _cell(text: str) -> str:
    return str(text).replace("|", "\\|") if text else ""


def render() -> str:
    out = ["# Config reference", "",
           "Generated from the schema (`taichi_mpm/config.py`) by `python -m taichi_mpm.tools.config_reference > "
           "docs/config.md`; do not edit by hand. The contract around it (CLI, Python API, output layout, exit "
           "codes) is in `docs/contract.md`.", "", CONVENTIONS,
           "## Keys", "",
           "| key | type | default | unit | allowed | meaning |", "| --- | --- | --- | --- | --- | --- |"]
    for key, text, default, allowed, note in walk():
        unit, meaning = DESCRIPTIONS.get(key, ("?", "UNDOCUMENTED"))
        if note:
            meaning = f"{meaning} ({note})" if not note.startswith("same") else f"{meaning}; {note}"
        out.append(f"| `{key}` | {_cell(text)} | {_cell(f'`{default}`' if default and default != 'required' else default)} "
                   f"| {_cell(unit)} | {allowed} | {_cell(meaning)} |")
    out += ["", "In the shape rows the note in parentheses names the shape types that have the key.", "",
            "A wall face is a wall type alone (`y_min: slip`) or a mapping with friction "
            "(`y_min: {type: slip, friction: 0.3}`); a frictionless face is written back as its plain string.", "",
            "## Output fields", "",
            "Per-particle fields of the VTU and NPZ snapshots: the standard set (\"always written\") plus "
            "`output.fields`, or with `output.only_fields: true` the positions and exactly `output.fields`; also the "
            "colour fields of frames and the window (`taichi_mpm/fields.py`). VTU vectors have 3 components "
            "(zero beyond dim), tensors 9 (the full 3x3 tensor, row-major), floating values in the run's precision "
            "(float32 in an f32 run); NPZ arrays are unpadded, with the stress both as `stress` (N, d, d) and "
            "`stress3` (N, 3, 3). The cost column is the VTU's uncompressed bytes per particle and snapshot in an f32 "
            "(f64) run; the arrays are zlib-compressed, to about 0.7-0.9 of that for floats and almost nothing for "
            "labels. Every VTU also holds the positions (12 (24) B) and the vertex cells (9 B, about 3 B "
            "compressed).", "",
            "| field | unit | kind | always written | VTU bytes a particle | meaning |",
            "| --- | --- | --- | --- | --- | --- |"]
    cost = {"scalar": "4 (8)", "vector": "12 (24)", "tensor": "36 (72)", "label": "4"}
    for name, f in fields.REGISTRY.items():
        present = name == "damage" or name in fields.STATES
        always = "yes" + (" (when present)" if present else "") if name in fields.ALWAYS else ""
        out.append(f"| `{name}` | {_cell(f.unit)} | {f.kind} | {always} | {cost[f.kind]} | {_cell(f.meaning)} |")
    out += ["", "## Probes", "", PROBES_DOC, "",
            "## diagnostics.csv", "",
            "One row per output time, columns in this order (" + ", ".join(io.diagnostics_columns(3)) + " in 3D; "
            "1D and 2D have the momentum components up to dim, 1D no angular momentum). In 2D the energies and "
            "momenta are per metre of depth, in 1D per m^2 of cross-section.", "",
            "| column | unit | meaning |", "| --- | --- | --- |"]
    for name, (unit, meaning) in DIAGNOSTICS.items():
        out.append(f"| `{name}` | {_cell(unit)} | {_cell(meaning)} |")
    return "\n".join(out) + "\n"


def main() -> int:
    sys.stdout.write(render())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
