"""projector_display: shows each pattern on projector/pattern full-screen, and says when it was shown.

Subscribes projector/pattern (pattern_projector's: a line for phase-shift patterns, the full image for
the composite; mono8 or mono16). Each pattern is broadcast to the projector's width x height, shown 1:1
(never scaled: scaling would change the fringe period) at the top-left of SDL display `display`, full-
screen, and flipped (pygame, vsync'd where the driver offers it). Right after the flip the same image is
published on projector/displayed, stamped with that time: remap capture_sequence's projector/pattern to
it so camera frames are matched to when patterns were really on screen. 16-bit patterns are shown as
their top 8 bits (SDL surfaces have 8 bits per channel). A pattern that cannot be shown (encoding, size)
is rejected on /diagnostics and the node goes on; no display at start is one fatal line (exit status 2).
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Image

from fpp_msgs_py import ImageError, Qos, Topics, image_to_numpy, stamp_ns

from .common import declare, run
from .health import Health

PUMP_PERIOD_S = 0.05  # window events (expose, close) are handled this often, so the window stays responsive
GREYS = [(i, i, i) for i in range(256)]  # the palette of the 8-bit pattern surfaces
VIRTUAL_DRIVERS = ("offscreen", "dummy")  # SDL video drivers that show nothing on any screen


def screen_frame(pattern: np.ndarray, width: int, height: int) -> np.ndarray:
    """The height x width uint8 frame that shows a pattern: a 1 x width line (vertical fringes) repeated
    down, a height x 1 line (horizontal fringes) repeated across, a height x width image as it is; 16-bit
    values as their top 8 bits. ValueError for anything else."""
    if pattern.dtype == np.uint16:
        pattern = (pattern >> 8).astype(np.uint8)
    elif pattern.dtype != np.uint8:
        raise ValueError(f"{pattern.dtype} pixels cannot be shown: patterns are 8- or 16-bit (mono8, mono16)")
    if pattern.ndim != 2 or pattern.shape not in ((1, width), (height, 1), (height, width)):
        raise ValueError(
            f"a pattern of {' x '.join(map(str, pattern.shape))} (rows x columns) does not fit the projector's "
            f"{height} x {width} (parameters height, width): a 1 x {width} or {height} x 1 line or the full image"
        )
    return np.ascontiguousarray(np.broadcast_to(pattern, (height, width)))


def check_driver(driver: str, requested: str | None) -> None:
    """SDL falls back to a driver that shows nothing when it finds no screen: that is no display, unless
    SDL_VIDEODRIVER asked for it (tests, a run without a screen on purpose)."""
    if driver in VIRTUAL_DRIVERS and driver != (requested or "").strip().lower():
        raise OSError(
            f"no display to show patterns on: SDL found no screen (DISPLAY / WAYLAND_DISPLAY unset?) and fell back "
            f"to its {driver!r} driver, which shows nothing; set SDL_VIDEODRIVER={driver} to run without a screen"
        )


def import_pygame():
    """pygame, quiet, with the SDL hints a projector needs (set before SDL reads them, unless the user has)."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    # a full-screen window on the projector stays up when the operator clicks on the other screen
    os.environ.setdefault("SDL_VIDEO_MINIMIZE_ON_FOCUS_LOSS", "0")
    import pygame

    return pygame


class ProjectorDisplay(Node):
    def __init__(self, **kwargs):
        super().__init__("projector_display", **kwargs)
        self.health = Health(self)
        self.display = declare(self, "display", 0, "SDL display index of the projector (0: the first)", True)
        self.fullscreen = declare(
            self, "fullscreen", True, "full-screen on the display; false: a window of the patterns' size", True
        )
        self.width = declare(self, "width", 1280, "projector width, pixels (the pattern set's)", True)
        self.height = declare(self, "height", 800, "projector height, pixels (the pattern set's)", True)
        for name, value in (("width", self.width), ("height", self.height)):
            if not (isinstance(value, int) and value >= 2):
                raise ValueError(f"{name} must be at least 2 pixels, like a pattern set's, got {value!r}")
        if not (isinstance(self.display, int) and self.display >= 0):
            raise ValueError(f"display must be an SDL display index >= 0, got {self.display!r}")
        self.pygame = import_pygame()
        try:
            self.screen = self._open_screen()
        except self.pygame.error as e:
            self.pygame.quit()
            env = ", ".join(f"{k}={os.environ.get(k, '')!r}" for k in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"))
            raise OSError(f"no display to show patterns on: {e} ({env})") from None
        except (OSError, ValueError):
            self.pygame.quit()
            raise
        self.said_16_bit = False
        self.publisher = self.create_publisher(Image, Topics.DISPLAYED, Qos.FRAMES)
        self.create_subscription(Image, Topics.PATTERN, self._on_pattern, Qos.FRAMES)
        self.create_timer(PUMP_PERIOD_S, self._pump)

    def _open_screen(self):
        pg, log = self.pygame, self.get_logger()
        pg.display.init()
        driver = pg.display.get_driver()
        check_driver(driver, os.environ.get("SDL_VIDEODRIVER"))
        sizes = pg.display.get_desktop_sizes()
        if self.display >= len(sizes):
            listed = ", ".join(f"{i}: {w}x{h}" for i, (w, h) in enumerate(sizes))
            raise ValueError(f"display {self.display} does not exist; SDL ({driver}) sees {listed}")
        size = sizes[self.display] if self.fullscreen else (self.width, self.height)
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            if self.fullscreen:
                # SCALED gives an SDL renderer, which is what flips with vsync; its logical size is the
                # display's own, so the scale is exactly 1 (borderless full-screen, no mode change)
                screen = pg.display.set_mode(size, pg.FULLSCREEN | pg.SCALED, display=self.display, vsync=1)
                pg.mouse.set_visible(False)
            else:
                screen = pg.display.set_mode(size, 0, display=self.display)  # SCALED would zoom a window
        vsync = self.fullscreen and not any("vsync" in str(w.message) for w in said)
        for warning in said:
            if "vsync" not in str(warning.message):
                log.info(f"pygame: {warning.message}")  # e.g. no fast (accelerated) renderer: SDL draws in software
        screen.fill((0, 0, 0))
        pg.display.flip()
        where = f"display {self.display} ({driver}) {size[0]}x{size[1]}"
        mode = "full-screen" if self.fullscreen else "in a window"
        self.health.facts["display"] = f"{where}, {mode}, vsync {'on' if vsync else 'off'}"
        log.info(f"showing {self.width}x{self.height} patterns {mode} on {where}, 1:1 at the top-left")
        if not vsync:
            log.warn(
                "flips are not synchronized to the display's refresh"
                + (" (a window)" if not self.fullscreen else " (the driver offers no vsync)")
                + ": a pattern may reach the screen up to a refresh period after its stamp on projector/displayed"
            )
        if self.fullscreen and tuple(size) != (self.width, self.height):
            log.warn(
                f"display {self.display} runs at {size[0]}x{size[1]}, the patterns are {self.width}x{self.height}: "
                "they are shown 1:1 at the top-left, NOT scaled (scaling would change the fringe period)"
                + (", and cut off" if size[0] < self.width or size[1] < self.height else "")
                + "; set the display to the projector's native resolution"
            )
        return screen

    def _on_pattern(self, msg: Image):
        try:
            pattern = image_to_numpy(msg)
            frame = screen_frame(pattern, self.width, self.height)
        except (ImageError, ValueError) as e:
            self.health.report("patterns rejected", f"pattern not shown ({msg.encoding}): {e}")
            return
        if pattern.dtype == np.uint16 and not self.said_16_bit:
            self.said_16_bit = True
            self.get_logger().info("16-bit patterns are shown as their top 8 bits (SDL surfaces have 8 per channel)")
        pg = self.pygame
        surface = pg.image.frombuffer(frame, (self.width, self.height), "P")
        surface.set_palette(GREYS)
        self.screen.blit(surface, (0, 0))
        pg.display.flip()
        now = self.get_clock().now()
        self.health.latency((now.nanoseconds - stamp_ns(msg.header.stamp)) / 1e9)
        msg.header.stamp = now.to_msg()  # the same image and frame_id, stamped when it went on screen
        self.publisher.publish(msg)
        self.health.count("patterns shown")

    def _pump(self):
        for event in self.pygame.event.get():
            if event.type == self.pygame.QUIT:
                self.get_logger().info("the window was closed: shutting down")
                rclpy.try_shutdown(context=self.context)

    def destroy_node(self):
        self.pygame.quit()
        return super().destroy_node()


def main(args=None):
    run(ProjectorDisplay, args=args)


if __name__ == "__main__":
    main()
