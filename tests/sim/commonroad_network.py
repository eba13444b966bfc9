"""A hand-made CommonRoad file (format 2020a, as the reader reads real ones): two straight lanes in the
same direction, each continued by a successor, so that a route to the far left lanelet needs a lane
change; optionally a lanelet running the other way, and recorded cars driving straight along a lane."""
from __future__ import annotations

from pathlib import Path

LANE_WIDTH = 3.5
FIRST, SECOND = 100.0, 60.0  # m: the first lanelets' length, then their successors'


def _bound(name: str, y: float, x0: float, x1: float, reverse: bool = False) -> str:
    xs = [x0 + (x1 - x0) * i / 10 for i in range(11)]
    if reverse:
        xs = xs[::-1]
    points = "".join(f"<point><x>{x}</x><y>{y}</y></point>" for x in xs)
    return f"<{name}>{points}</{name}>"


def _lanelet(ident: int, centre_y: float, x0: float, x1: float, extra: str = "", reverse: bool = False) -> str:
    half = LANE_WIDTH / 2
    left, right = (centre_y - half, centre_y + half) if reverse else (centre_y + half, centre_y - half)
    return (f'<lanelet id="{ident}">{_bound("leftBound", left, x0, x1, reverse)}'
            f'{_bound("rightBound", right, x0, x1, reverse)}{extra}</lanelet>')


def _car(ident: int, x0: float, y: float, speed: float, steps: int, dt: float) -> str:
    states = "".join(f"<state><position><point><x>{x0 + speed * dt * k}</x><y>{y}</y></point></position>"
                     f"<orientation><exact>0.0</exact></orientation><time><exact>{k}</exact></time>"
                     f"<velocity><exact>{speed}</exact></velocity></state>" for k in range(1, steps + 1))
    return (f'<dynamicObstacle id="{ident}"><type>car</type><shape><rectangle><length>4.5</length>'
            f'<width>1.8</width></rectangle></shape><initialState><position><point><x>{x0}</x><y>{y}</y></point>'
            f'</position><orientation><exact>0.0</exact></orientation><time><exact>0</exact></time>'
            f'<velocity><exact>{speed}</exact></velocity></initialState><trajectory>{states}</trajectory>'
            f'</dynamicObstacle>')


def write_network(path: Path, *, goal: str = '<lanelet ref="4"/>', time: tuple[int, int] = (60, 140),
                  cars: tuple[tuple[float, float, float], ...] = (), opposite: bool = False,
                  start: tuple[float, float] = (10.0, 0.0), speed: float = 10.0) -> Path:
    """Lanelets 1 (right, y = 0) and 2 (left, y = 3.5) from x = 0 to 100, their successors 3 and 4 to
    x = 160; with ``opposite`` a lanelet 5 left of 2 running the other way.  ``cars``: (x at step 0,
    y, speed) of cars recorded driving straight on.  The planning problem 100 starts at ``start``
    heading along x at ``speed`` and ends at ``goal`` within steps ``time``."""
    dt = 0.1
    lanes = [
        _lanelet(1, 0.0, 0.0, FIRST, '<successor ref="3"/><adjacentLeft ref="2" drivingDir="same"/>'),
        _lanelet(2, LANE_WIDTH, 0.0, FIRST, '<successor ref="4"/><adjacentRight ref="1" drivingDir="same"/>'
                 + ('<adjacentLeft ref="5" drivingDir="opposite"/>' if opposite else "")),
        _lanelet(3, 0.0, FIRST, FIRST + SECOND, '<predecessor ref="1"/><adjacentLeft ref="4" drivingDir="same"/>'),
        _lanelet(4, LANE_WIDTH, FIRST, FIRST + SECOND,
                 '<predecessor ref="2"/><adjacentRight ref="3" drivingDir="same"/>'),
    ]
    if opposite:
        lanes.append(_lanelet(5, 2 * LANE_WIDTH, 0.0, FIRST, '<adjacentLeft ref="2" drivingDir="opposite"/>',
                              reverse=True))
    obstacles = "".join(_car(200 + i, *car, steps=time[1], dt=dt) for i, car in enumerate(cars))
    problem = (f'<planningProblem id="100"><initialState><position><point><x>{start[0]}</x><y>{start[1]}</y>'
               f'</point></position><orientation><exact>0.0</exact></orientation><time><exact>0</exact></time>'
               f'<velocity><exact>{speed}</exact></velocity><yawRate><exact>0.0</exact></yawRate><slipAngle>'
               f'<exact>0.0</exact></slipAngle></initialState><goalState><position>{goal}</position>'
               f'<time><intervalStart>{time[0]}</intervalStart><intervalEnd>{time[1]}</intervalEnd></time>'
               f'</goalState></planningProblem>')
    path.write_text(f"<?xml version='1.0' encoding='UTF-8'?>\n<commonRoad timeStepSize=\"{dt}\" "
                    f'commonRoadVersion="2020a" benchmarkID="ZAM_Handmade-1_1_T-1" date="2026-11-29">'
                    f"<location><geoNameId>-999</geoNameId><gpsLatitude>999.0</gpsLatitude><gpsLongitude>999.0"
                    f"</gpsLongitude></location>{''.join(lanes)}{obstacles}{problem}</commonRoad>")
    return path
