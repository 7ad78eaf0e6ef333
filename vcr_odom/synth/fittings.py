"""Fitting out the indoor floor (:mod:`~vcr_odom.synth.indoor`): the meshes of a
:class:`~vcr_odom.synth.floorplan.FloorPlan`, one part per side of the ring plus a shell.

A side's part holds its corridor (floor, ceiling with a step where the last side's height differs,
lights, beams, a duct), its halls (columns, benches, plants, a glass front now and then), the rooms
behind its walls (partitions, windows in the exterior wall, a door open into the room or shut,
furniture) and what stands at its walls every 0.3-3.5 m: closed doors, niches, pilasters, boards,
radiators, extinguishers, cabinets, benches, plants, bins, machines. Anything against a corridor wall
is at most the corridor's half-width less :data:`~vcr_odom.synth.floorplan.OBJECT_SETBACK` deep and
stays clear of the corners' arcs; nothing hangs below
:data:`~vcr_odom.synth.floorplan.HUNG_CLEARANCE` over a corridor. Each side is drawn from its own
generator, so the parts are a pure function of the plan and the seed.
"""

from __future__ import annotations

import math

import numpy as np

from vcr_odom.synth.corridors import LATERAL_MAX, TURN_RADIUS
from vcr_odom.synth.floorplan import (
    CEILING_HEIGHT,
    HUNG_CLEARANCE,
    OBJECT_SETBACK,
    TOP,
    FloorPlan,
    Frame,
    Hall,
    Room,
    Wall,
)
from vcr_odom.synth.mesh import MeshBuilder, MeshPart, Surface


def fit_out(plan: FloorPlan, seed: int) -> list[MeshPart]:
    """The shell (a slab under and over everything), then one part per side of the ring."""
    fitter = _Fitter(plan, seed)
    return [fitter.shell()] + [fitter.side(i) for i in range(plan.ring.n)]


class _Fitter:
    """Meshes for a plan; it cuts the doors and niches it places into the plan's walls."""

    def __init__(self, plan: FloorPlan, seed: int) -> None:
        self.plan = plan
        self.seed = seed
        self.ring, self.walls, self.rooms, self.halls = plan.ring, plan.walls, plan.rooms, plan.halls
        self.ceilings, self.wall_albedo = plan.ceilings, plan.wall_albedo

    def shell(self) -> MeshPart:
        """A slab under and over everything: no ray leaves the building, whatever it slips through."""
        rects = np.array(self.plan.obstacles)
        lo, hi = rects[:, :2].min(axis=0) - 1.0, rects[:, 2:].max(axis=0) + 1.0
        mesh = MeshBuilder()
        plan = [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]
        mesh.quad([(x, y, -0.3) for x, y in plan], Surface.SIDEWALK, 0.3)
        mesh.quad([(x, y, TOP) for x, y in plan], Surface.WALL, 0.5)
        return mesh.build()

    def side(self, i: int) -> MeshPart:
        """Side ``i`` of the ring: its corridor, both walls and what stands at them, its halls and the
        rooms behind its walls."""
        rng = np.random.default_rng([self.seed, 46, i])
        mesh = MeshBuilder()
        self._corridor(rng, mesh, i)
        for hall in self.halls:
            if hall.side == i:
                self._hall(rng, mesh, hall)
        for w in (2 * i, 2 * i + 1):
            for room in (r for r in self.rooms if r.wall == w):
                self._room(rng, mesh, room)
        for w in (2 * i, 2 * i + 1):
            self._wall_features(rng, mesh, w)
            self.walls[w].build(mesh)
        return mesh.build()

    def _corridor(self, rng: np.random.Generator, mesh: MeshBuilder, i: int) -> None:
        """Floor, ceiling (a step down or up where the last side's differs), lights, beams and ducts."""
        ring = self.ring
        start, d, normal, length = ring.side(i)
        a_prev, a, a_next = ring.half_widths[i - 1], ring.half_widths[i], ring.half_widths[(i + 1) % ring.n]
        h, h_prev = float(self.ceilings[i]), float(self.ceilings[i - 1])
        centre = Frame(start, d, normal)  # d: across, + towards the core
        u0, u1 = a_prev, length + a_next
        centre.floor(mesh, (u0, u1), (-a, a), 0.0, rng.uniform(0.2, 0.45))
        centre.floor(mesh, (u0, u1), (-a, a), h, rng.uniform(0.6, 0.85))
        if abs(h - h_prev) > 1e-6:
            centre.box(mesh, (u0 - 0.03, u0), (-a, a), (min(h, h_prev), max(h, h_prev)), Surface.WALL, 0.7)
        # Lights flush with the ceiling, every 2.2-4 m, in the middle or staggered.
        u = u0 + rng.uniform(0.5, 2.0)
        square = rng.random() < 0.5
        while u < u1 - 1.0:
            size = (0.6, 0.6) if square else (1.2, 0.25)
            v = rng.choice([0.0, 0.0, -0.35 * a, 0.35 * a])
            centre.box(
                mesh, (u, u + size[0]), (v - size[1] / 2, v + size[1] / 2), (h - 0.06, h), Surface.METAL, 0.8
            )
            u += rng.uniform(2.2, 4.0)
        if rng.random() < 0.5 and h - HUNG_CLEARANCE >= 0.15:  # beams across
            depth = min(0.45, h - HUNG_CLEARANCE)
            u = u0 + rng.uniform(1.0, 4.0)
            while u < u1 - 1.0:
                centre.box(mesh, (u, u + rng.uniform(0.3, 0.5)), (-a, a), (h - depth, h), Surface.WALL, 0.65)
                u += rng.uniform(4.0, 9.0)
        if rng.random() < 0.35 and h - 0.45 >= HUNG_CLEARANCE:  # a duct along one wall
            side = rng.choice([-1.0, 1.0])
            width = rng.uniform(0.3, 0.5)
            v = side * (a - 0.05 - width / 2)
            stop = u0 + (u1 - u0) * rng.uniform(0.5, 1.0)
            centre.box(
                mesh, (u0, stop), (v - width / 2, v + width / 2), (h - 0.45, h - 0.2), Surface.METAL, 0.55
            )

    def _hall(self, rng: np.random.Generator, mesh: MeshBuilder, hall: Hall) -> None:
        """The hall's opening, walls (a glazed back wall now and then), floor, ceiling, columns
        (not in a turning hall) and furniture at its back."""
        wall = self.walls[2 * hall.side + 1]
        frame, t = wall.frame, wall.thickness
        h = float(self.ceilings[hall.side])
        u0, u1, depth = hall.u0, hall.u1, hall.depth
        wall.cuts.append((u0, u1, 0.0, h))
        albedo = rng.uniform(0.5, 0.85)
        frame.box(mesh, (u0 - 0.15, u0), (t, depth), (0.0, TOP), Surface.WALL, albedo)
        frame.box(mesh, (u1, u1 + 0.15), (t, depth), (0.0, TOP), Surface.WALL, albedo)
        back = (depth, depth + 0.3)
        if rng.random() < 0.5:  # a glass front: mullions, a spandrel, panes
            frame.box(mesh, (u0 - 0.15, u1 + 0.15), back, (0.0, 0.4), Surface.WALL, albedo)
            frame.box(mesh, (u0 - 0.15, u1 + 0.15), back, (2.6, TOP), Surface.WALL, albedo)
            frame.box(mesh, (u0, u1), (depth + 0.14, depth + 0.16), (0.4, 2.6), Surface.GLASS, 0.2)
            for u in np.arange(u0, u1 + 1e-6, (u1 - u0) / max(1, round((u1 - u0) / 1.5))):
                frame.box(mesh, (u - 0.04, u + 0.04), back, (0.4, 2.6), Surface.METAL, 0.5)
        else:
            frame.box(mesh, (u0 - 0.15, u1 + 0.15), back, (0.0, TOP), Surface.WALL, albedo)
        frame.floor(mesh, (u0, u1), (0.0, depth), 0.0, rng.uniform(0.2, 0.5))
        frame.floor(mesh, (u0, u1), (0.0, depth), hall.ceiling, rng.uniform(0.6, 0.85))
        if hall.turn:
            # The walker swings up to 2 turn radii + LATERAL_MAX aside of the centre line: its back
            # keeps 0.6 m clear.
            a = self.ring.half_widths[hall.side]
            room = depth - (2.0 * TURN_RADIUS[1] + LATERAL_MAX - a) - 0.7
            if room >= 0.4:
                for u in np.arange(u0 + 0.5, u1 - 1.5, rng.uniform(2.5, 4.0)):
                    self._bench(rng, mesh, frame, u, rng.uniform(1.2, 2.0), (depth - min(room, 0.5), depth))
            return
        # Columns: a row just beyond the corridor's wall line, another in the middle of deep halls.
        rows = [0.6] + ([depth / 2 + 0.3] if depth > 4.5 else [])
        round_columns, size = rng.random() < 0.5, rng.uniform(0.35, 0.6)
        for d in rows:
            count = max(1, round((u1 - u0) / rng.uniform(3.5, 5.0)))
            for u in u0 + (np.arange(count) + 0.5) * (u1 - u0) / count:
                if round_columns:
                    mesh.cylinder(
                        (*frame.at(u, d + size / 2), 0.0), (0, 0, 1), size / 2, TOP, Surface.WALL, albedo, 12
                    )
                else:
                    frame.box(
                        mesh, (u - size / 2, u + size / 2), (d, d + size), (0.0, TOP), Surface.WALL, albedo
                    )
        for u in np.arange(u0 + 0.5, u1 - 1.5, rng.uniform(2.5, 4.5)):
            kind = rng.random()
            if kind < 0.5:
                self._bench(rng, mesh, frame, u, rng.uniform(1.2, 2.0), (depth - 0.45, depth))
            elif kind < 0.8:
                self._plant(rng, mesh, frame, u + 0.4, depth - 0.45)
            else:
                frame.box(mesh, (u, u + 1.6), (depth - 0.9, depth - 0.2), (0.0, 1.05), Surface.WOOD, 0.4)

    def _room(self, rng: np.random.Generator, mesh: MeshBuilder, room: Room) -> None:
        """A room's walls (windows in an exterior one), floor, ceiling, door and furniture."""
        wall = self.walls[room.wall]
        frame = wall.frame
        d0, d1 = room.d0, room.d0 + room.depth
        albedo = rng.uniform(0.45, 0.85)
        frame.box(mesh, (room.u0 - 0.05, room.u0 + 0.05), (d0, d1), (0.0, TOP), Surface.WALL, albedo)
        if not any(r.wall == room.wall and abs(r.u0 - room.u1) < 1e-9 for r in self.rooms):
            frame.box(mesh, (room.u1 - 0.05, room.u1 + 0.05), (d0, d1), (0.0, TOP), Surface.WALL, albedo)
        back = (d1, d1 + (0.3 if room.exterior else 0.1))
        if room.exterior:
            sill, head = rng.uniform(0.8, 1.0), rng.uniform(2.1, 2.4)
            count = max(1, int((room.u1 - room.u0) / 2.5))
            width = min(1.6, (room.u1 - room.u0) / count - 0.6)
            edges = [room.u0 - 0.05]
            for k in range(count):
                centre = room.u0 + (k + 0.5) * (room.u1 - room.u0) / count
                edges += [centre - width / 2, centre + width / 2]
                frame.box(
                    mesh,
                    (centre - width / 2, centre + width / 2),
                    (d1 + 0.14, d1 + 0.16),
                    (sill, head),
                    Surface.GLASS,
                    0.2,
                )
                frame.box(
                    mesh, (centre - width / 2, centre + width / 2), back, (0.0, sill), Surface.WALL, albedo
                )
                frame.box(
                    mesh, (centre - width / 2, centre + width / 2), back, (head, TOP), Surface.WALL, albedo
                )
            edges.append(room.u1 + 0.05)
            for a, b in zip(edges[0::2], edges[1::2], strict=True):
                frame.box(mesh, (a, b), back, (0.0, TOP), Surface.WALL, albedo)
        else:
            frame.box(mesh, (room.u0 - 0.05, room.u1 + 0.05), back, (0.0, TOP), Surface.WALL, albedo)
        frame.floor(mesh, (room.u0, room.u1), (d0, d1), 0.0, rng.uniform(0.15, 0.5))
        frame.floor(mesh, (room.u0, room.u1), (d0, d1), rng.uniform(*CEILING_HEIGHT), rng.uniform(0.6, 0.85))
        # The door: open into the room (a leaf swung 70-115 deg) or shut, a panel set into the wall.
        width = (
            rng.uniform(1.6, 1.9)
            if room.u1 - room.u0 > 5.0 and rng.random() < 0.2
            else rng.uniform(0.85, 1.0)
        )
        u = rng.uniform(room.u0 + 0.3, max(room.u0 + 0.3, room.u1 - 0.3 - width))
        height = rng.uniform(2.0, 2.3)
        opened = rng.random() < 0.55
        self._door(rng, mesh, wall, u, width, height, opened)
        if opened:
            hinge_left = rng.random() < 0.5
            angle = math.radians(rng.uniform(70.0, 115.0))
            leaf = width if width < 1.2 else width / 2
            hinge = np.array([u if hinge_left else u + width, d0])
            along = np.array([math.cos(angle) * (1 if hinge_left else -1), math.sin(angle)])
            across = np.array([-along[1], along[0]]) * 0.04
            plan = [hinge, hinge + leaf * along, hinge + leaf * along + across, hinge + across]
            world = [frame.at(*p) for p in plan]
            corners = [(*p, 0.01) for p in world] + [(*p, height - 0.01) for p in world]
            mesh.hexahedron(corners, Surface.WOOD, rng.uniform(0.3, 0.5))
        self._furnish(rng, mesh, frame, room)

    def _door(
        self,
        rng: np.random.Generator,
        mesh: MeshBuilder,
        wall: Wall,
        u: float,
        width: float,
        height: float,
        opened: bool,
    ) -> None:
        """A doorway cut into a corridor wall with its casing; shut, a panel recessed into the wall."""
        frame, t = wall.frame, wall.thickness
        wall.cuts.append((u, u + width, 0.0, height))
        wall.taken.append((u - 0.1, u + width + 0.1))
        casing = rng.uniform(0.2, 0.6)
        frame.box(mesh, (u - 0.07, u), (-0.02, 0.0), (0.0, height + 0.07), Surface.WOOD, casing)
        frame.box(
            mesh, (u + width, u + width + 0.07), (-0.02, 0.0), (0.0, height + 0.07), Surface.WOOD, casing
        )
        frame.box(mesh, (u, u + width), (-0.02, 0.0), (height, height + 0.07), Surface.WOOD, casing)
        if opened:
            frame.floor(mesh, (u, u + width), (0.0, t), 0.0, rng.uniform(0.2, 0.45))
            return
        recess = rng.uniform(0.04, max(0.05, t - 0.06))
        surface = Surface.METAL if rng.random() < 0.3 else Surface.WOOD
        frame.box(
            mesh, (u, u + width), (recess, recess + 0.045), (0.0, height), surface, rng.uniform(0.25, 0.6)
        )

    def _furnish(self, rng: np.random.Generator, mesh: MeshBuilder, frame: Frame, room: Room) -> None:
        """Desks and tables (a top on legs), shelves and cabinets against the walls, chairs, sofas."""
        ua, ub = room.u0 + 0.1, room.u1 - 0.1
        da, db = room.d0 + 0.6, room.d0 + room.depth - 0.1  # the door's swing stays clear-ish
        for _ in range(int(rng.integers(2, 8))):
            kind = rng.random()
            if kind < 0.3:  # a table or desk
                w, dep, top = rng.uniform(1.0, 1.8), rng.uniform(0.6, 0.9), rng.uniform(0.72, 0.76)
                u, d = rng.uniform(ua, max(ua, ub - w)), rng.uniform(da, max(da, db - dep))
                frame.box(
                    mesh, (u, u + w), (d, d + dep), (top - 0.03, top), Surface.WOOD, rng.uniform(0.3, 0.6)
                )
                for lu in (u, u + w - 0.05):
                    for ld in (d, d + dep - 0.05):
                        frame.box(
                            mesh, (lu, lu + 0.05), (ld, ld + 0.05), (0.0, top - 0.03), Surface.METAL, 0.4
                        )
            elif kind < 0.55:  # shelves or a cabinet against the back wall
                w, dep = rng.uniform(0.6, 2.0), rng.uniform(0.3, 0.5)
                height = rng.uniform(1.8, 2.2) if rng.random() < 0.6 else rng.uniform(0.8, 1.3)
                u = rng.uniform(ua, max(ua, ub - w))
                frame.box(
                    mesh, (u, u + w), (db - dep, db), (0.0, height), Surface.WOOD, rng.uniform(0.25, 0.6)
                )
            elif kind < 0.75:  # a cabinet against a side wall
                w, dep, height = rng.uniform(0.5, 1.2), rng.uniform(0.4, 0.6), rng.uniform(0.8, 2.0)
                d = rng.uniform(da, max(da, db - w))
                u = (ua, ua + dep) if rng.random() < 0.5 else (ub - dep, ub)
                frame.box(mesh, u, (d, d + w), (0.0, height), Surface.METAL, rng.uniform(0.3, 0.6))
            elif kind < 0.92:  # a chair: seat and back
                u, d = rng.uniform(ua, max(ua, ub - 0.45)), rng.uniform(da, max(da, db - 0.45))
                frame.box(
                    mesh, (u, u + 0.45), (d, d + 0.45), (0.0, 0.46), Surface.RUBBER, rng.uniform(0.1, 0.4)
                )
                frame.box(mesh, (u, u + 0.45), (d + 0.4, d + 0.45), (0.46, 0.9), Surface.RUBBER, 0.3)
            else:  # a sofa
                w = rng.uniform(1.4, 2.0)
                u, d = rng.uniform(ua, max(ua, ub - w)), rng.uniform(da, max(da, db - 0.85))
                frame.box(mesh, (u, u + w), (d, d + 0.85), (0.0, 0.45), Surface.RUBBER, rng.uniform(0.1, 0.4))
                frame.box(mesh, (u, u + w), (d + 0.65, d + 0.85), (0.45, 0.85), Surface.RUBBER, 0.3)

    def _wall_features(self, rng: np.random.Generator, mesh: MeshBuilder, w: int) -> None:
        """What a corridor wall carries between its doors, every 0.3-3.5 m: closed doors, niches,
        pilasters, boards, radiators, extinguishers, cabinets, benches, plants, bins, machines; each
        at most the corridor's half-width less :data:`OBJECT_SETBACK` deep."""
        wall = self.walls[w]
        side = w // 2
        allowance = min(0.75, self.ring.half_widths[side] - OBJECT_SETBACK)
        lo, hi = self.plan.object_zone(side)
        lo, hi = max(lo, wall.u0 + 0.2), min(hi, wall.u1 - 0.2)
        kinds = {"board": 2.0, "radiator": 1.5, "niche": 1.2, "door": 1.5, "pilaster": 1.0}
        needs = {"extinguisher": (0.18, 0.6), "cabinet": (0.4, 1.5), "bench": (0.38, 1.0), "plant": (0.55, 1.0),
                 "bin": (0.35, 0.7), "machine": (0.72, 0.4)}  # fmt: skip
        kinds |= {kind: weight for kind, (depth, weight) in needs.items() if allowance >= depth}
        names = sorted(kinds)
        weights = np.array([kinds[n] for n in names])
        u = lo + rng.uniform(0.0, 1.5)
        while u < hi:
            kind = names[int(rng.choice(len(names), p=weights / weights.sum()))]
            width = {"pilaster": rng.uniform(0.3, 0.6), "extinguisher": 0.3, "plant": 0.6, "bin": 0.45,
                     "machine": rng.uniform(0.8, 1.0), "door": rng.uniform(0.85, 1.0)}.get(kind, rng.uniform(0.6, 2.2))  # fmt: skip
            if u + width <= hi and wall.free(u, u + width):
                self._feature(rng, mesh, wall, kind, u, width, allowance)
                if kind != "door":  # a door takes its own stretch
                    wall.taken.append((u, u + width))
            u += width + rng.uniform(0.3, 3.5)

    def _feature(
        self,
        rng: np.random.Generator,
        mesh: MeshBuilder,
        wall: Wall,
        kind: str,
        u: float,
        width: float,
        allowance: float,
    ) -> None:
        frame, t = wall.frame, wall.thickness
        span = (u, u + width)
        if kind == "door":
            self._door(rng, mesh, wall, u, width, rng.uniform(2.0, 2.3), opened=False)
        elif kind == "niche":  # recessed into the wall: from the floor, or a wall niche above a sill
            depth = rng.uniform(0.15, 0.45)
            z0, z1 = (
                (0.0, rng.uniform(2.0, 2.4))
                if rng.random() < 0.5
                else (rng.uniform(0.7, 1.0), rng.uniform(1.8, 2.2))
            )
            wall.cuts.append((u, u + width, z0, z1))
            albedo = rng.uniform(0.4, 0.8)
            frame.box(mesh, span, (depth, max(depth + 0.05, t)), (z0, z1), Surface.WALL, albedo)
            if depth > t:
                frame.box(mesh, (u - 0.05, u), (t, depth + 0.05), (z0, z1), Surface.WALL, albedo)
                frame.box(
                    mesh, (u + width, u + width + 0.05), (t, depth + 0.05), (z0, z1), Surface.WALL, albedo
                )
                frame.box(mesh, span, (t, depth), (z1, z1 + 0.05), Surface.WALL, albedo)
                if z0 > 0.0:
                    frame.box(mesh, span, (t, depth), (z0 - 0.05, z0), Surface.WALL, albedo)
        elif kind == "pilaster":
            depth = min(allowance, rng.uniform(0.12, 0.3)) if allowance > 0.12 else 0.08
            frame.box(mesh, span, (-depth, 0.0), (0.0, TOP), Surface.WALL, self.wall_albedo)
        elif kind == "board":
            z0 = rng.uniform(0.9, 1.3)
            frame.box(
                mesh,
                span,
                (-0.03, 0.0),
                (z0, z0 + rng.uniform(0.5, 1.0)),
                Surface.SIGN,
                rng.uniform(0.3, 0.9),
            )
        elif kind == "radiator":
            frame.box(
                mesh, span, (-0.1, 0.0), (0.15, rng.uniform(0.6, 0.8)), Surface.METAL, rng.uniform(0.5, 0.8)
            )
        elif kind == "extinguisher":
            z0 = rng.uniform(0.1, 0.9)
            base = (*frame.at(u + 0.15, -0.09), z0)
            mesh.cylinder(base, (0, 0, 1), 0.08, 0.55, Surface.METAL, 0.5, 10)
        elif kind == "cabinet":
            depth = rng.uniform(0.4, min(0.6, allowance))
            frame.box(
                mesh, span, (-depth, 0.0), (0.0, rng.uniform(0.9, 2.0)), Surface.METAL, rng.uniform(0.3, 0.7)
            )
        elif kind == "bench":
            self._bench(rng, mesh, frame, u, width, (-min(0.45, allowance), 0.0))
        elif kind == "plant":
            self._plant(rng, mesh, frame, u + 0.3, -0.27)
        elif kind == "bin":
            radius = rng.uniform(0.14, 0.16)
            mesh.cylinder((*frame.at(u + 0.22, -radius - 0.01), 0.0), (0, 0, 1), radius, rng.uniform(0.5, 0.8),
                          Surface.METAL, rng.uniform(0.3, 0.6), 10)  # fmt: skip
        else:  # a vending machine or a copier
            depth = rng.uniform(0.7, allowance)
            frame.box(
                mesh, span, (-depth, 0.0), (0.0, rng.uniform(1.1, 1.85)), Surface.METAL, rng.uniform(0.3, 0.7)
            )

    def _bench(
        self,
        rng: np.random.Generator,
        mesh: MeshBuilder,
        frame: Frame,
        u: float,
        width: float,
        d: tuple[float, float],
    ) -> None:
        """A bench ``width`` long from ``u``, its seat over ``d`` (across the frame), on two legs."""
        albedo = rng.uniform(0.3, 0.6)
        frame.box(mesh, (u, u + width), d, (0.4, 0.46), Surface.WOOD, albedo)
        for lu in (u + 0.05, u + width - 0.1):
            frame.box(mesh, (lu, lu + 0.05), d, (0.0, 0.4), Surface.METAL, 0.4)

    def _plant(self, rng: np.random.Generator, mesh: MeshBuilder, frame: Frame, u: float, d: float) -> None:
        """A pot with a leafy crown, centred at ``(u, d)``; at most 0.27 m from there in plan."""
        pot, crown = rng.uniform(0.15, 0.2), rng.uniform(0.16, 0.22)
        height = rng.uniform(0.35, 0.5)
        centre = frame.at(u, d)
        mesh.cylinder((*centre, 0.0), (0, 0, 1), pot, height, Surface.WOOD, rng.uniform(0.2, 0.5), 10)
        radii = (crown, crown, rng.uniform(0.3, 0.6))
        mesh.blob((*centre, height + radii[2]), radii, rng, Surface.VEGETATION, rng.uniform(0.3, 0.5), 0.15)
