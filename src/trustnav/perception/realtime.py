"""Real-time person following: the search for new people runs beside the frame loop (issue 20).

:class:`RealtimePoseBackend` is a drop-in pose backend (callable on a frame) built from the same two
BlazePose graphs as :class:`~trustnav.perception.mediapipe_backend.MediaPipePoseBackend`, split over
the two cores differently:

- **one core searches**: a background thread runs the tiled detector over the newest frame it was
  handed, again and again (a full search of a 640x480 frame takes ~0.35 s on one core); regions of
  people it finds are handed to the frame loop, which fits them on the frame it is at (people move
  a few pixels in a search's time; the landmark region tolerates that);
- **the other follows**: each frame, the people already found are fitted from the region of their
  own landmarks, as MediaPipe's video mode does. With ``landmark_every`` = k a person is fitted on
  one frame in k (people are staggered over the frames) and carried on the others by the velocity
  of its last fits: its box and keypoints moved, its landmarks marked ``extra["predicted"]``.

The first frame after :meth:`reset` is searched in full before it is answered, so a stream starts
with everybody in view. With ``RealtimeConfig(search_frames=k)`` the search runs in step with the
frames instead of on its own thread, its findings handed over as if it had taken k frames: the same
behaviour, deterministic (simulated drives, tests), but not faster. ``stats`` reports the searches
done and their mean duration: the time to first detection of a person who appears later is at most
about two search durations.
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.mediapipe_backend import (
    SEGMENT_SCORE,
    MediaPipeConfig,
    MediaPipePoseBackend,
    _merge_regions,
    _region_box,
    _same_region,
    one_box_per_person,
    sharpened,
    tiles,
)
from trustnav.perception.types import Person, box_iou, check_frame

__all__ = ["SEARCH_SECONDS", "RealtimeConfig", "RealtimePoseBackend", "modelled_search_frames"]


@dataclass(frozen=True)
class RealtimeConfig:
    """landmark_every: a followed person is fitted on one frame in this many (1: every frame) and
    moved by its velocity in between. max_search_age: regions from a search whose frame is more than
    this many frames old are dropped (the person has moved too far for its region). carry_frames: a
    person whose fit fails (or lands on someone else) is carried by its velocity for up to this many
    frames beyond ``landmark_every``, long enough for the search to find it again; the carried
    person's landmarks say ``extra["predicted"]``. search_frames: None (default) runs the search on
    its own thread, as fast as the machine allows (what it finds, and when, depends on the machine
    and its load); an integer k makes the backend deterministic: the search runs in step with the
    frame loop on the frame it starts from, and hands over what it found as if it had taken k
    frames (its batches spread over them, the segmentation proposals last), the next search starting
    when one ends; an episode is then a pure function of its frames (:func:`modelled_search_frames`
    turns a search time into k)."""

    landmark_every: int = 2
    max_search_age: int = 15
    carry_frames: int = 8
    search_frames: int | None = None

    def __post_init__(self) -> None:
        if self.search_frames is not None and (
            isinstance(self.search_frames, bool) or not isinstance(self.search_frames, int) or self.search_frames < 1
        ):
            raise ValueError(f"search_frames must be None (threaded) or an integer >= 1, got {self.search_frames!r}")
        if not isinstance(self.landmark_every, int) or not 1 <= self.landmark_every <= 10:
            raise ValueError(f"landmark_every must be an integer in [1, 10], got {self.landmark_every!r}")
        if not isinstance(self.carry_frames, int) or not 0 <= self.carry_frames <= 100:
            raise ValueError(f"carry_frames must be an integer in [0, 100], got {self.carry_frames!r}")
        if not isinstance(self.max_search_age, int) or self.max_search_age < 1:
            raise ValueError(f"max_search_age must be an integer >= 1, got {self.max_search_age!r}")


#: Seconds a search of a whole frame takes on one core of the 2-core machine (the mean of
#: ``RealtimePoseBackend.stats``: 0.35-0.5 s at 640x480, more at 1280x720), the default of
#: :func:`modelled_search_frames`.
SEARCH_SECONDS = 0.5


def modelled_search_frames(fps: float, search_seconds: float = SEARCH_SECONDS) -> int:
    """The frames a search of ``search_seconds`` spans in a stream of ``fps`` frames/s (at least 1):
    ``RealtimeConfig.search_frames`` for a deterministic run."""
    if not (math.isfinite(fps) and fps > 0 and math.isfinite(search_seconds) and search_seconds > 0):
        raise ValueError(f"fps and search_seconds must be positive, got {fps!r} and {search_seconds!r}")
    return max(1, math.ceil(search_seconds * fps - 1e-9))


@dataclass
class _Followed:
    """A person followed from frame to frame."""

    roi: NDArray[np.float64]  # region for the next fit, as the last fit gave it
    score: float
    fitted: Person  # as last fitted
    fitted_at: int  # frame index of that fit
    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))  # pixels per frame
    person: Person | None = None  # this frame's: fitted, or carried by the velocity

    def __post_init__(self) -> None:
        if self.person is None:
            self.person = self.fitted


@dataclass
class _Search:
    frame_index: int
    seconds: float
    people: list  # [(next region, score, person)] as found on that frame


class RealtimePoseBackend(MediaPipePoseBackend):
    """Pose backend for streams: asynchronous search, following at frame rate (module docstring).

    Always in video mode; call :meth:`reset` between streams and :meth:`close` at the end (it stops
    the search thread).
    """

    def __init__(self, config: MediaPipeConfig | None = None, realtime: RealtimeConfig | None = None) -> None:
        config = replace(config or MediaPipeConfig(), workers=2)
        super().__init__(config, video=True)
        # mediapipe 0.10.14 warns on every graph call (protobuf's GetPrototype). A scoped filter
        # (``protobuf_warning_ignored``) is not thread-safe with two threads calling graphs, so this
        # backend ignores that one message for the rest of the process.
        warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype", category=UserWarning)
        self.realtime = realtime or RealtimeConfig()
        self._follower, self._searcher = self._all_graphs
        self._lock = threading.Condition()
        self._pending: tuple[int, NDArray[np.uint8]] | None = None
        self._found: list[_Search] = []
        self._busy = False
        self._stop = False
        self._people: list[_Followed] = []
        self._searches: list[float] = []
        self._thread: threading.Thread | None = None
        self._turn = 0  # searches started: which share of the segmentation tiles, whether the body search
        # deterministic mode (RealtimeConfig.search_frames): (frame index handed over at, _Search)
        self._scheduled: list[tuple[int, _Search]] = []
        self._next_search = 1  # the frame the next search starts from
        self._previous: NDArray[np.uint8] | None = None  # the frame the last search started from

    # -- the search thread -------------------------------------------------------------------

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._search_loop, name="trustnav-search", daemon=True)
            self._thread.start()

    def _search_loop(self) -> None:
        previous: NDArray[np.uint8] | None = None
        while True:
            with self._lock:
                while self._pending is None and not self._stop:
                    self._lock.wait()
                if self._stop:
                    return
                index, frame, known = self._pending
                self._pending = None
                self._busy = True
            t0 = time.perf_counter()

            def publish(people: list, index: int = index, t0: float = t0) -> None:
                with self._lock:
                    self._found.append(_Search(index, time.perf_counter() - t0, people))

            try:
                self._search(frame, known, previous, publish)
            except Exception:  # a failed search loses the rest of that search only
                pass
            previous = frame
            with self._lock:
                self._busy = False
                self._searches.append(time.perf_counter() - t0)
                self._lock.notify_all()

    def _search(
        self,
        frame: NDArray[np.uint8],
        known: list[NDArray[np.float64]],
        previous: NDArray[np.uint8] | None,
        publish: Callable[[list], None],
    ) -> None:
        """New people on ``frame`` (searcher core): the tiled detector, then the landmark check on
        the regions that are not people followed already; what is found is published after each
        batch of :data:`SEARCH_BATCH` windows, [(next region, score, person)], so that a person
        found early in a search is followed before the search ends. Windows are searched in order of
        :func:`search_order` (the whole frame, then where the image changed and its side edges);
        then the HOG body-shape search (:mod:`~trustnav.perception.body_search`) and person
        segmentation (:mod:`~trustnav.perception.segment_search`) propose the people the detector
        does not see, each published when it ends."""
        h, w = frame.shape[:2]
        search = sharpened(frame, self.config.sharpen, self.config.sharpen_sigma)
        windows = search_order(tiles(h, w, self.config), frame, previous)
        checked: list[NDArray[np.float64]] = list(known)
        for start in range(0, len(windows), SEARCH_BATCH):
            regions = [r for win in windows[start : start + SEARCH_BATCH] for r in self._searcher.detect(search, win)]
            out = []
            for rois, score in _merge_regions(regions):
                if any(_same_region(rois[0], r) for r in checked):
                    continue
                checked.append(rois[0])
                res = self._searcher.landmarks_of_group(
                    frame, rois, lambda lm, roi, s=score: self._person(lm, s, w, h, roi)
                )
                if res is not None:
                    out.append((res[1], score, res[3]))
                    checked.append(res[1])
            if out:
                publish(out)
        on_searcher = lambda fn, items: [fn(self._searcher, item) for item in items]  # noqa: E731
        turn, self._turn = self._turn, self._turn + 1
        if self.config.body_search and turn % self.config.body_frames == 0:
            # the people found by their body's shape (body_search), on one search in body_frames
            known = [_region_box(r) for r in checked]
            found = self._body_search(frame, self._searcher.bodies(frame), known, w, h, on_searcher)
            checked += [res[1] for res in found]
            if found:
                publish([(res[1], SEGMENT_SCORE, res[3]) for res in found])
        if self.config.segment_search:  # the people the detector does not see (segment_search)
            found = self._segment_search(  # a share of the tiles per search, in turn
                frame, [_region_box(r) for r in checked], w, h, turn, on_searcher
            )  # fmt: skip
            if found:
                publish([(res[1], SEGMENT_SCORE, res[3]) for res in found])

    def _hand_over(self, index: int, frame: NDArray[np.uint8], known: list[NDArray[np.float64]]) -> list[_Search]:
        """Give the searcher the newest frame (replacing one it has not started) and the regions of
        the people followed; take what earlier searches found."""
        with self._lock:
            self._pending = (index, frame, known)
            found, self._found = self._found, []
            self._lock.notify_all()
        return found

    def _in_step(self, index: int, frame: NDArray[np.uint8], known: list[NDArray[np.float64]]) -> list[_Search]:
        """Deterministic mode: start a search on this frame if the last one has ended (run here,
        in the frame loop), and take what is due by this frame."""
        k = self.realtime.search_frames
        assert k is not None
        if index >= self._next_search:
            batches: list[list] = []
            t0 = time.perf_counter()
            self._search(frame, known, self._previous, batches.append)
            self._searches.append(time.perf_counter() - t0)
            for j, people in enumerate(batches):  # spread over the search's frames, in order
                due = index + math.ceil((j + 1) * k / len(batches))
                self._scheduled.append((due, _Search(index, (due - index) / k, people)))
            self._previous = frame
            self._next_search = index + k
        due = [s for at, s in self._scheduled if at <= index]
        self._scheduled = [(at, s) for at, s in self._scheduled if at > index]
        return due

    def _quiet_searcher(self) -> None:
        """Wait for a search under way to end and drop what it found (start of a stream)."""
        with self._lock:
            self._pending = None
            while self._busy:
                self._lock.wait()
            self._found = []

    # -- the frame loop ----------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the people followed (call between streams)."""
        self._quiet_searcher()
        self._people = []
        self._scheduled, self._next_search, self._previous = [], 1, None
        self._turn = 0
        super().reset()

    def close(self) -> None:
        """Stop the search thread and release the graphs."""
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        super().close()

    @property
    def stats(self) -> dict[str, float]:
        """Searches completed and their mean and largest duration (s)."""
        s = self._searches
        return {"searches": len(s), "search_mean_s": float(np.mean(s)) if s else math.nan,
                "search_max_s": float(np.max(s)) if s else math.nan}  # fmt: skip

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]:
        """People in ``frame`` (H x W x 3 uint8 RGB), answered without waiting for a search (except
        on the first frame of a stream)."""
        frame = check_frame(frame)
        h, w = frame.shape[:2]
        index = self._frame_index
        t0 = time.perf_counter()
        known = [f.roi for f in self._people if f.fitted_at == index - 1]  # found last frame
        deterministic = self.realtime.search_frames is not None
        if index == 0:
            self._quiet_searcher()
            groups = self.detect(sharpened(frame, self.config.sharpen, self.config.sharpen_sigma))
            found: list = []
            if not deterministic:
                self._start()  # the search thread starts on the next frame (this one is searched)
        else:
            groups = []
            searches = self._in_step(index, frame, known) if deterministic else self._hand_over(index, frame, known)
            found = [p for s in searches if index - s.frame_index <= self.realtime.max_search_age for p in s.people]
        t1 = time.perf_counter()
        people = self._follow(frame, index, groups, found, w, h)
        if index == 0:
            people = self._first_proposals(frame, people, w, h)
        self.last_timing = {"detection": t1 - t0, "landmarks": time.perf_counter() - t1}
        self._frame_index += 1
        return people

    def _first_proposals(self, frame: NDArray[np.uint8], people: list[Person], w: int, h: int) -> list[Person]:
        """The first frame as the offline backend's: the people segmentation and the body-shape
        search propose beside the detector's, then one box per person (followed from then on)."""
        searches = []
        if self.config.segment_search:
            searches.append(lambda known: self._segment_search(frame, known, w, h, turn=0))
        if self.config.body_search:
            searches.append(lambda known: self._body_search(frame, self._follower.bodies(frame), known, w, h))
        for search in searches:
            for res in search([p.bbox for p in people]):
                self._people.append(_Followed(res[1], SEGMENT_SCORE, res[3], 0))
                people.append(res[3])
        keep = one_box_per_person(people, self.config.duplicate_iou)
        self._people = [self._people[i] for i in keep]
        return [people[i] for i in keep]

    def _fit(self, frame: NDArray[np.uint8], rois: NDArray[np.float64], score: float, w: int, h: int) -> tuple | None:
        # no refit on tried regions (FOLLOW_TRIES) here: the frame loop has no time for two more landmark
        # calls per lost person, and it carries a lost person until a search finds them again
        def accept(lm: NDArray[np.float64], roi: NDArray[np.float64]) -> Person | None:
            return self._person(lm, score, w, h, roi)

        return self._follower.landmarks_or_redetect(frame, rois, accept, tries=())

    def _follow(self, frame: NDArray[np.uint8], index: int, groups: list, found: list, w: int, h: int) -> list[Person]:
        """Fit (or carry) the people followed, fit the regions of ``groups`` (the first frame's
        search) and the people a search ``found`` on an earlier frame that nobody covers now."""
        k = self.realtime.landmark_every
        fitted: list[_Followed] = []  # fitted on this frame
        carried: list[_Followed] = []  # moved by their velocity: not due, not found, or taken by another
        prior: list[_Followed] = []  # each fit's state before it, carried if the fit is dropped
        for n, f in enumerate(self._people):
            ahead = f.velocity * (index - f.fitted_at)
            moved = replace(f, person=_moved(f.fitted, ahead, w, h))
            if index - f.fitted_at >= k or (index + n) % k == 0:
                roi = f.roi.copy()
                roi[:2] += ahead  # where the person should be now
                res = self._fit(frame, roi[None, :], f.score, w, h)
                if res is not None:
                    person = res[3]
                    fitted.append(_Followed(res[1], f.score, person, index, _velocity(f, person, index)))
                    prior.append(moved)
                    continue
            carried.append(moved)
        # people a search found on an earlier frame whom no fit of this frame covers: fitted now
        for roi, score, person in found:
            if any(box_iou(person.bbox, g.person.bbox) >= CARRY_MAX_IOU for g in fitted):
                continue
            res = self._fit(frame, roi[None, :], score, w, h)
            if res is not None:
                fitted.append(_Followed(res[1], score, res[3], index))
                prior.append(None)
        # the first frame's search
        for rois, score in groups:
            if any(_same_region(rois[0], f.roi) for f in fitted):
                continue
            res = self._fit(frame, rois, score, w, h)
            if res is not None:
                fitted.append(_Followed(res[1], score, res[3], index))
                prior.append(None)
        # one per person among the fits (two followed regions can converge on one person: the
        # other one is carried) ...
        keep = one_box_per_person([f.person for f in fitted], self.config.duplicate_iou)
        people = [fitted[i] for i in keep]
        carried += [p for i, p in enumerate(prior) if i not in keep and p is not None]
        # ... then the carried ones that no fit covers, while they are recent and in view
        limit = self.realtime.landmark_every + self.realtime.carry_frames
        for f in carried:
            box = f.person.bbox
            if index - f.fitted_at > limit or box[2] <= 1 or box[0] >= w - 2:
                continue
            if all(box_iou(box, g.person.bbox) < CARRY_MAX_IOU for g in people):
                people.append(f)
        self._people = people
        return [f.person for f in people]


#: Windows the search thread runs before it publishes what they found.
SEARCH_BATCH = 6


def search_order(
    windows: list[tuple[int, int, int, int]], frame: NDArray[np.uint8], previous: NDArray[np.uint8] | None
) -> list[tuple[int, int, int, int]]:
    """The search windows, whole frame first, then by where people appear: the share of the window
    where the image changed since the previous search (a person walking in, a car's motion), plus a
    bonus for windows on the left and right edges (where people enter the view)."""
    if len(windows) <= 1:
        return list(windows)
    h, w = frame.shape[:2]
    change = None
    if previous is not None and previous.shape == frame.shape:
        small = (max(1, w // 8), max(1, h // 8))
        import cv2

        a = cv2.resize(frame, small, interpolation=cv2.INTER_AREA).astype(np.int16)
        b = cv2.resize(previous, small, interpolation=cv2.INTER_AREA).astype(np.int16)
        change = (np.abs(a - b).max(axis=2) > 20).astype(float)

    def priority(win: tuple[int, int, int, int]) -> float:
        x0, y0, x1, y1 = win
        edge = 0.5 if x0 <= 0 or x1 >= w else 0.0
        if change is None:
            return edge
        cut = change[y0 // 8 : max(y0 // 8 + 1, y1 // 8), x0 // 8 : max(x0 // 8 + 1, x1 // 8)]
        return edge + float(cut.mean()) if cut.size else edge

    rest = sorted(windows[1:], key=priority, reverse=True)
    return [windows[0], *rest]


#: A carried person is dropped when a fit of this frame overlaps it this much (the same person).
CARRY_MAX_IOU = 0.3


def _velocity(f: _Followed, person: Person, index: int) -> NDArray[np.float64]:
    """Pixels per frame from ``f``'s last fit to ``person``; zero when the box jumped by more than
    half its height (the fit landed on someone else), capped at a tenth of the height per frame
    (a brisk walk seen at 10 frames/s, with the camera's own motion)."""
    height = float(person.bbox[3] - person.bbox[1])
    step = _centre(person) - _centre(f.fitted)
    if float(np.hypot(*step)) > 0.5 * height:
        return np.zeros(2)
    v = step / max(1, index - f.fitted_at)
    speed = float(np.hypot(*v))
    return v if speed <= 0.1 * height else v * (0.1 * height / speed)


def _centre(p: Person) -> NDArray[np.float64]:
    return np.array([(p.bbox[0] + p.bbox[2]) / 2, (p.bbox[1] + p.bbox[3]) / 2])


def _moved(p: Person, shift: NDArray[np.float64], w: int, h: int) -> Person:
    """``p`` (as last fitted) moved by ``shift`` pixels, box kept inside the image."""
    dx, dy = float(shift[0]), float(shift[1])
    x1, y1, x2, y2 = p.bbox
    bw, bh = x2 - x1, y2 - y1
    nx1 = float(np.clip(x1 + dx, 0.0, w - 1.0 - min(bw, w - 2.0)))
    ny1 = float(np.clip(y1 + dy, 0.0, h - 1.0 - min(bh, h - 2.0)))
    dx, dy = nx1 - x1, ny1 - y1
    extra = dict(p.extra)
    if "blazepose" in extra:
        lm = extra["blazepose"].copy()
        lm[:, 0] += dx
        lm[:, 1] += dy
        extra["blazepose"] = lm
    extra["predicted"] = True
    return Person(
        bbox=np.array([x1 + dx, y1 + dy, x2 + dx, y2 + dy]),
        keypoints=p.keypoints + np.array([dx, dy]),
        confidences=p.confidences,
        score=p.score,
        extra=extra,
    )
