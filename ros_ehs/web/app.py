# Copyright 2026 ros_ehs contributors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""
The station's web server: the page, its live frames and its buttons (aiohttp, no ROS).

Routes:

* ``GET /``: the page (``static/index.html``); ``/static/...`` its scripts, the charting
  library among them (uPlot, shipped in the package: a rig's network is offline);
* ``GET /ws``: a WebSocket; the server sends a frame (:meth:`Desk.frame`) ``push_rate``
  times a second, the board with it :data:`BOARD_HZ` times a second (the first frame always);
  the page sends ``{"drawn": n}`` when it has drawn its ``n``-th frame, and ``{"span": s}`` to
  change its time base. At most :data:`WINDOW` frames are on their way undrawn
  (:class:`Pacer`): a page that cannot draw every frame (a busy browser or machine) gets fewer,
  never a queue of stale ones in front of its buttons' answers. Uncompressed: the frames are
  mostly a base64 block, and compressing them cost the station more than sending them;
* ``GET /api/frame?span=s``: one frame, for a script or a test;
* ``POST /api/meters/reset``: the meters' min/max and cycles forgotten (the station's own
  state, nothing on the axis; the access rule applies);
* ``POST /api/action/<name>`` (JSON ``{"token": ..., "confirm": true}``): one of
  :data:`ACTIONS`, answered ``{"ok", "message"}``; ``next`` (the campaign's next specimen)
  takes ``"specimen"``, the id on the coupon (empty: the plan's).

An action goes to the :class:`Desk` (the station node calls the same services a ROS client
does), after the access rule (:class:`~ros_ehs.core.station.access.Access`): refused with its
reason (HTTP 403), and the refusal is logged like the action. A request must be JSON and, if
it names an ``Origin``, come from this page's own origin (another web site open in the same
browser cannot press a button). Turning hydraulics on or off needs ``confirm`` (the page asks
first). Every action, done or refused, is handed to :meth:`Desk.log_action` with its origin
(the peer's address and browser). A closed page changes nothing on the axis: the server only
ever acts on a request.
"""

from __future__ import annotations

import asyncio
import json
import math
from pathlib import Path
import threading
from typing import Protocol
import weakref

from aiohttp import web, WSCloseCode, WSMsgType
from ros_ehs.core.campaign.spec import SPECIMEN_MAX
from ros_ehs.core.station.access import Access
from ros_ehs.core.station.scope import TIME_BASES

__all__ = ['ACTIONS', 'BOARD_HZ', 'CONFIRM', 'Desk', 'make_app', 'Pacer', 'STATIC',
           'StationServer', 'STOP_TIMEOUT', 'WINDOW']

#: the open pages' WebSockets (each is closed when the station stops)
PAGES = web.AppKey('pages', weakref.WeakSet)
#: seconds the station waits for its web server to stop
STOP_TIMEOUT = 5.0
STATIC = Path(__file__).resolve().with_name('static')
#: what a page may ask: the controller's and the procedure's services
ACTIONS = ('reset', 'enable', 'disable', 'start', 'hold', 'resume', 'stop', 'next')
#: actions that need ``confirm`` in the request (the page asks the operator first)
CONFIRM = ('enable', 'disable')
DEFAULT_SPAN = 5.0
#: how often a page gets the board (statuses, detectors, events) [Hz]: read by eye
BOARD_HZ = 5.0
#: frames a page may have on their way, sent and not yet drawn
WINDOW = 2


class Pacer:
    """
    Which ticks of a page's frame clock send a frame, and which frames carry the board.

    The server ticks ``push_rate`` times a second (:meth:`tick`). A tick sends a frame unless
    ``window`` frames are sent and not yet drawn (:meth:`take_drawn`): then it is skipped, and
    the page, once it has drawn, gets the newest frame at the next tick. Without that, a
    browser that draws slower than the frames come (a loaded machine) queued them: each
    frame, and each button's answer behind them, came later than the last, until the
    socket's buffers were full and the connection's heartbeat failed. The board goes with
    the first frame and every ``board_every`` ticks; a board tick that sent nothing hands the
    board to the next frame sent.
    """

    def __init__(self, window: int = WINDOW, board_every: int = 1) -> None:
        for name, v in (('window', window), ('board_every', board_every)):
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f'`{name}` = {v!r} must be an int >= 1')
        self.window = window
        self.board_every = board_every
        self.ticks = 0
        self.sent = 0
        self.drawn = 0
        self._board_due = False

    def tick(self) -> tuple[bool, bool]:
        """Count one tick; return (send a frame now, with the board)."""
        if self.ticks % self.board_every == 0:
            self._board_due = True
        self.ticks += 1
        if self.sent - self.drawn >= self.window:
            return False, False
        board, self._board_due = self._board_due, False
        self.sent += 1
        return True, board

    def take_drawn(self, n: object) -> bool:
        """
        Take the page's word that it has drawn ``n`` frames in all; True if taken.

        A count that is not a whole number, goes back, or exceeds the frames sent is ignored
        (the page's word can only open the window as far as the frames really sent).
        """
        if isinstance(n, int) and not isinstance(n, bool) and self.drawn < n <= self.sent:
            self.drawn = n
            return True
        return False


class Desk(Protocol):
    """What the web server needs from the station node."""

    def frame(self, span: float, board: bool = True) -> dict:
        """Return one frame for time base ``span`` [s] (with the board when ``board``)."""

    async def act(self, action: str, specimen: str = '') -> tuple[bool, str]:
        """
        Do ``action`` through its service; (done, the answer or why not).

        ``specimen``: the id ``next`` gives the campaign node.
        """

    def log_action(self, action: str, origin: str, result: str, reason: str) -> None:
        """Log an action (done, refused or unanswered) with where it came from."""

    def page_count(self, delta: int) -> None:
        """Count an open page (+1) or a closed one (-1)."""

    def reset_meters(self) -> None:
        """Forget the meters' min/max and cycles (nothing on the axis)."""


def _origin(request: web.Request) -> str:
    agent = request.headers.get('User-Agent', '?')
    return f'{request.remote} ({agent[:160]})'


def _span(text: str | None) -> float:
    try:
        span = float(text) if text is not None else DEFAULT_SPAN
    except ValueError:
        span = math.nan
    if span not in TIME_BASES:
        raise web.HTTPBadRequest(text=f'time base {text!r} s is not one of {TIME_BASES}')
    return span


def _same_origin(request: web.Request) -> bool:
    origin = request.headers.get('Origin')
    return origin is None or origin in (f'{request.scheme}://{request.host}',)


async def _gate(request: web.Request, access: Access) -> tuple[dict, str]:
    """
    Return a request's JSON body and why it may not act ('' when it may).

    A JSON object, from this page's own origin, allowed by the access rule (its ``token``).
    """
    if request.content_type != 'application/json':
        return {}, 'an action must be a JSON request'
    if not _same_origin(request):
        return {}, f'refused: a page from {request.headers.get("Origin")} may not act here'
    try:
        body = await request.json()
    except ValueError:
        return {}, 'the request is not valid JSON'
    if not isinstance(body, dict):
        return {}, 'the request must be a JSON object'
    decision = access.decide(request.remote, body.get('token'))
    return body, '' if decision.allowed else decision.why


def make_app(desk: Desk, access: Access, push_rate: float = 25.0) -> web.Application:
    """Return the station's aiohttp application."""
    if not (math.isfinite(push_rate) and push_rate > 0):
        raise ValueError(f'`push_rate` = {push_rate!r} Hz must be finite and > 0')
    routes = web.RouteTableDef()

    @routes.get('/')
    async def index(request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / 'index.html', headers={'Cache-Control': 'no-cache'})

    @routes.get('/favicon.ico')
    async def favicon(request: web.Request) -> web.Response:
        return web.Response(status=204)

    @routes.get('/api/frame')
    async def frame(request: web.Request) -> web.Response:
        span = _span(request.query.get('span'))
        body = desk.frame(span)
        body['may_act'] = access.decide(request.remote, request.query.get('token'))._asdict()
        return web.json_response(body)

    @routes.post('/api/action/{name}')
    async def action(request: web.Request) -> web.Response:
        name = request.match_info['name']
        if name not in ACTIONS:
            return web.json_response({'ok': False, 'message': f'unknown action {name!r}; '
                                      f'actions: {list(ACTIONS)}'}, status=404)
        origin = _origin(request)
        body, why = await _gate(request, access)
        if not why and name in CONFIRM and body.get('confirm') is not True:
            why = f'{name}: hydraulics change only with "confirm": true (the page asks first)'
        specimen = body.get('specimen', '')
        if not why and name == 'next' and not (isinstance(specimen, str) and
                                               len(specimen) <= SPECIMEN_MAX):
            why = f'next: "specimen" must be a text of at most {SPECIMEN_MAX} characters'
        if why:
            desk.log_action(name, origin, 'refused', why)
            return web.json_response({'ok': False, 'message': why}, status=403)
        try:
            ok, message = await (desk.act(name, specimen.strip()) if name == 'next' else
                                 desk.act(name))
        except asyncio.TimeoutError:
            desk.log_action(name, origin, 'unanswered', 'no answer from the node')
            return web.json_response({'ok': False, 'message': f'{name}: no answer from the '
                                      'node (is it running?)'}, status=504)
        desk.log_action(name, origin, 'done' if ok else 'refused', message)
        return web.json_response({'ok': ok, 'message': message})

    @routes.post('/api/meters/reset')
    async def meters_reset(request: web.Request) -> web.Response:
        _, why = await _gate(request, access)
        if why:
            return web.json_response({'ok': False, 'message': why}, status=403)
        desk.reset_meters()
        return web.json_response({'ok': True, 'message': 'meters reset'})

    @routes.get('/ws')
    async def websocket(request: web.Request) -> web.StreamResponse:
        span = _span(request.query.get('span'))      # a bad time base: 400, before the upgrade
        ws = web.WebSocketResponse(heartbeat=10.0, compress=False)
        await ws.prepare(request)
        request.app[PAGES].add(ws)
        may = access.decide(request.remote, request.query.get('token'))._asdict()
        desk.page_count(1)

        pacer = Pacer(WINDOW, max(1, round(push_rate / BOARD_HZ)))

        async def listen() -> None:
            nonlocal span
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    said = json.loads(msg.data)
                except ValueError:
                    continue            # not JSON: ignored, the page goes on
                if not isinstance(said, dict):
                    continue
                if 'drawn' in said:
                    pacer.take_drawn(said['drawn'])
                if 'span' in said:
                    try:
                        span = _span(str(said['span']))
                    except web.HTTPBadRequest:
                        pass            # a bad time base is ignored: the page keeps its own

        listener = asyncio.ensure_future(listen())
        try:
            period = 1.0 / push_rate
            loop = asyncio.get_running_loop()
            next_t = loop.time()
            while not ws.closed and not listener.done():
                send, board = pacer.tick()
                if send:
                    body = desk.frame(span, board=board)
                    body['may_act'] = may
                    await ws.send_str(json.dumps(body, allow_nan=False))
                next_t += period
                await asyncio.sleep(max(0.0, next_t - loop.time()))
                next_t = max(next_t, loop.time() - period)    # after a stall: no burst
        except (ConnectionResetError, RuntimeError):
            pass                        # the page went away mid-send
        finally:
            listener.cancel()
            desk.page_count(-1)
        return ws

    async def close_pages(app: web.Application) -> None:
        # aiohttp's graceful shutdown: an open page's handler would hold the cleanup until
        # the runner's shutdown timeout; each page is told 1001 (going away) and reconnects
        for ws in set(app[PAGES]):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b'station stopping')

    app = web.Application()
    app[PAGES] = weakref.WeakSet()
    app.on_shutdown.append(close_pages)
    app.add_routes(routes)
    app.router.add_static('/static', STATIC, append_version=False)
    return app


class StationServer:
    """Serve an application on a thread of its own (its own asyncio loop)."""

    def __init__(self, app: web.Application, host: str, port: int) -> None:
        self.app = app
        self.host = host
        self.port = port
        self.loop = asyncio.new_event_loop()
        self._runner: web.AppRunner | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name='ehs-station-web', daemon=True)

    def start(self, timeout: float = 10.0) -> int:
        """Start serving; return the port (an OSError when the address cannot be bound)."""
        self._thread.start()
        if not self._ready.wait(timeout):
            raise OSError(f'the station did not start serving on {self.host}:{self.port} '
                          f'within {timeout} s')
        if self._error is not None:
            raise OSError(f'cannot serve on {self.host}:{self.port}: {self._error}')
        return self.port

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self._runner = web.AppRunner(self.app, access_log=None)
            self.loop.run_until_complete(self._runner.setup())
            site = web.TCPSite(self._runner, self.host, self.port)
            self.loop.run_until_complete(site.start())
            self.port = int(self._runner.addresses[0][1])
        except BaseException as err:        # noqa: B902 (reported by start())
            self._error = err
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()
        self.loop.run_until_complete(self._runner.cleanup())

    def stop(self, timeout: float = STOP_TIMEOUT) -> bool:
        """Stop serving (open pages are closed); return False if it did not within ``timeout``."""
        if self._thread.is_alive():
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout)
        return not self._thread.is_alive()
