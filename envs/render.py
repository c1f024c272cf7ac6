"""Rendering of MapEnv: lanes culled to the view via the network's grid hash, crosswalk stripes,
stop lines, signal heads in their colours, stop signs, pedestrians and the ego route."""
from __future__ import annotations

import math
import os

import numpy as np
import pygame
from highway_env.envs.common.graphics import EnvViewer
from highway_env.vehicle.graphics import VehicleGraphics

from .network import GRID_CELL_M, flip
from .vehicles import Pedestrian

ASPHALT = (80, 80, 85)
GROUND = (120, 150, 110)
WHITE = (240, 240, 240)
SIGNAL_RGB = {"green": (30, 220, 60), "amber": (255, 190, 0), "red": (230, 30, 30)}
ROUTE_RGB = (60, 140, 255)
PED_RGB = (255, 120, 0)
MARKING_RGB = {"solid_white": WHITE, "curb": WHITE, "dotted_white": WHITE,
               "solid_yellow": (240, 200, 40), "dotted_yellow": (240, 200, 40)}
MARKING_WIDTH_M = 0.3
DASH_M, DASH_PERIOD_M = 3.0, 6.0  # dotted boundaries: 3 m dashes every 6 m

# SDL (the viewer's pygame.display.init) would otherwise replace SIGTERM's default action with a
# handler that only queues a quit event nobody reads: a rendering process, a rollout worker
# recording a GIF, would ignore SIGTERM (read when SDL starts, so set before any viewer)
os.environ.setdefault("SDL_NO_SIGNAL_HANDLERS", "1")


class MapViewer(EnvViewer):
    """EnvViewer that draws only what is visible and the traffic-control layer."""

    def display(self) -> None:
        if not self.enabled:
            return
        env = self.env
        surf = self.sim_surface
        surf.move_display_window_to(self.window_position())
        surf.fill(GROUND)
        net = env.net
        m = net.hdmap
        x0, y0 = surf.origin
        x1 = x0 + surf.get_width() / surf.scaling
        y1 = y0 + surf.get_height() / surf.scaling
        ks = set()
        for gx in range(math.floor(x0 / GRID_CELL_M), math.floor(x1 / GRID_CELL_M) + 1):
            for gy in range(math.floor(y0 / GRID_CELL_M), math.floor(y1 / GRID_CELL_M) + 1):
                cell = net._cells.get((gx, gy))
                if cell is not None:
                    ks.update(cell[0].tolist())
        visible = [net.lane_ids[k] for k in sorted(ks)]
        junctions = {m.lanes[l].junction_id for l in visible} - {None}
        for lid in visible:  # pavement
            ln = m.lanes[lid]
            poly = np.concatenate([flip(ln.left_boundary), flip(ln.right_boundary)[::-1]])
            pygame.draw.polygon(surf, ASPHALT, [surf.vec2pix(p) for p in poly])
        for jid in junctions:
            pygame.draw.polygon(surf, ASPHALT, [surf.vec2pix(p) for p in flip(m.junctions[jid].polygon)])
        for lid in visible:  # markings of road lanes
            ln = m.lanes[lid]
            if ln.junction_id is None:
                self._marking(surf, flip(ln.left_boundary), ln.left_boundary_type)
                self._marking(surf, flip(ln.right_boundary), ln.right_boundary_type)
        for c in m.crosswalks.values():
            if c.junction_id in junctions:
                self._crosswalk(surf, net, c.id)
        ctrl = env.control
        for table, kind in ((m.signals, "signal"), (m.stop_signs, "stop")):
            for c in table.values():
                if c.junction_id not in junctions:
                    continue
                line = flip(c.stop_line)
                pygame.draw.line(surf, WHITE, surf.vec2pix(line[0]), surf.vec2pix(line[-1]), max(2, surf.pix(0.4)))
                pos = surf.vec2pix(flip(c.position)[0])
                if kind == "signal":
                    state = ctrl.signal_state(c.id)
                    pygame.draw.circle(surf, (20, 20, 20), pos, max(4, surf.pix(1.1)))
                    pygame.draw.circle(surf, SIGNAL_RGB[state], pos, max(3, surf.pix(0.8)))
                    # also colour the stop line so the state reads at a glance
                    pygame.draw.line(surf, SIGNAL_RGB[state], surf.vec2pix(line[0]), surf.vec2pix(line[-1]),
                                     max(2, surf.pix(0.3)))
                else:
                    r = max(4, surf.pix(1.0))
                    pts = [(pos[0] + r * math.cos(math.pi / 8 + k * math.pi / 4),
                            pos[1] + r * math.sin(math.pi / 8 + k * math.pi / 4)) for k in range(8)]
                    pygame.draw.polygon(surf, (200, 0, 0), pts)
                    pygame.draw.polygon(surf, WHITE, pts, 1)
        if env.config.get("show_route") and env.vehicle is not None:
            route = np.concatenate([net.lane_of[l].points for l in env.vehicle.lane_route])
            pygame.draw.lines(surf, ROUTE_RGB, False, [surf.vec2pix(p) for p in route], max(1, surf.pix(0.3)))
        for o in env.road.objects:
            if isinstance(o, Pedestrian) and surf.is_visible(o.position):
                pygame.draw.circle(surf, PED_RGB, surf.vec2pix(o.position), max(3, surf.pix(0.5)))
                pygame.draw.circle(surf, (0, 0, 0), surf.vec2pix(o.position), max(3, surf.pix(0.5)), 1)
        for v in env.road.vehicles:
            if surf.is_visible(v.position):
                VehicleGraphics.display(v, surf, offscreen=self.offscreen)
        if not self.offscreen:
            self.screen.blit(surf, (0, 0))
            if env.config["real_time_rendering"]:
                self.clock.tick(env.config["simulation_frequency"])
            pygame.display.flip()

    @staticmethod
    def _marking(surf, points: np.ndarray, kind: str) -> None:
        """A lane boundary along its polyline (highway-env's solid line is one chord, which cuts
        across curved lanes such as a ring road's): solid, or dashes for dotted; none if virtual."""
        if len(points) < 2 or kind not in MARKING_RGB:
            return
        rgb, width = MARKING_RGB[kind], max(1, surf.pix(MARKING_WIDTH_M))
        if not kind.startswith("dotted"):
            pygame.draw.lines(surf, rgb, False, [surf.vec2pix(p) for p in points], width)
            return
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
        for s0 in np.arange(0.0, cum[-1], DASH_PERIOD_M):
            s = np.linspace(s0, min(s0 + DASH_M, cum[-1]), 3)
            dash = np.column_stack([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])])
            pygame.draw.lines(surf, rgb, False, [surf.vec2pix(p) for p in dash], width)

    @staticmethod
    def _crosswalk(surf, net, cw_id: str) -> None:
        a, b, width = net.crosswalk_axes[cw_id]
        d = b - a
        length = float(np.hypot(*d))
        if length < 1e-6:
            return
        u = d / length
        n = np.array([-u[1], u[0]])
        k = int(length // 1.0)
        for i in range(k):
            if i % 2:
                continue
            c0 = a + u * (i + 0.1)
            c1 = a + u * (i + 0.9)
            quad = [c0 - n * width / 2, c1 - n * width / 2, c1 + n * width / 2, c0 + n * width / 2]
            pygame.draw.polygon(surf, WHITE, [surf.vec2pix(p) for p in quad])
