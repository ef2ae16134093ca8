"""The ball model's public interface: parameters, equations, integrator, table geometry.

Everything another package (perception's filter, strike, identification, the reference)
needs of the ball model is imported from here; the modules behind it (params, model,
integrate, table, predict) are implementation. Units are SI, spin in rad/s, positions in the
``table`` frame (MODEL.md). The state of a ball is ``s = [p (m), v (m/s), w (rad/s)]`` (9,);
compiled kernels take the model as the packed float64 array of
:meth:`ModelParams.packed`, indexed by the ``I_*`` constants generated from the declaration
:data:`FIELDS`.

Equations (MODEL.md, paper numbering):

- :func:`flight_derivative` / :func:`flight_acceleration`: eq. 8 (with its effects);
  :func:`flight_jacobian`: its Jacobian, for filters.
- :func:`table_rebound` / :func:`table_rebound_inplace`: eqs. 1-6 (:func:`table_restitution`:
  e_t with its effects; :func:`edge_distance`: a bounce's distance to the table's edge).
- :func:`racket_rebound` / :func:`racket_rebound_inplace`: eq. 7.

Integration: :func:`rk4_step` (one step of eq. 8; :func:`rk4_advance` into a new array),
:func:`rollout_kernel` (events: bounce, net, plane, floor, roll, timeout) and :func:`rollout`
(its Python face); predict.py's :func:`flight_kernel` (one flight leg to its first contact,
the table as a solid body: :func:`solid_gap`), :func:`landing_flight` on it (the one landing
flight of tt, a ball leaving the racket until its first contact: prediction, strike solver,
in-zone ensemble) and :func:`landing_kernel` (that flight classified into a status, as
``predict_landing`` reports it).
"""

from . import params as _params
from .integrate import (
    DEFAULT_STEP,
    EVENT_BOUNCE,
    EVENT_FLOOR,
    EVENT_NAMES,
    EVENT_NET,
    EVENT_PLANE,
    EVENT_ROLL,
    EVENT_TIMEOUT,
    ROLL_SPEED,
    STOP_AT_NET,
    STOP_AT_PLANE,
    Event,
    rk4_advance,
    rk4_step,
    rollout,
    rollout_kernel,
)
from .model import (
    edge_distance,
    edge_gradient,
    flight_acceleration,
    flight_derivative,
    flight_jacobian,
    racket_rebound,
    racket_rebound_inplace,
    table_rebound,
    table_rebound_inplace,
    table_restitution,
)
from .params import (
    DRAG_SPEED_REF,
    EDGE_LENGTH_REF,
    EFFECT_FIELDS,
    EFFECTS,
    FIELD,
    FIELDS,
    IMPACT_SPEED_REF,
    INDEX,
    INDEX_NAMES,
    LIFT_SPIN_RATIO_REF,
    N_PACKED,
    PACKED_FIELDS,
    SLIP_SPEED_REF,
    SLOT_BOUNDS,
    Effect,
    Field,
    ModelParams,
    load_model,
)
from .predict import (
    CONTACT_EDGE,
    CONTACT_FLOOR,
    CONTACT_KINDS,
    CONTACT_NET,
    CONTACT_OFF,
    CONTACT_PLANE,
    CONTACT_POST,
    CONTACT_TIMEOUT,
    CONTACT_TOP,
    FL_CROSS_T,
    FL_CROSS_X,
    FL_CROSS_Y,
    FL_KIND,
    FL_NET_T,
    FL_NET_Y,
    FL_NET_Z,
    FL_S,
    FL_SAMPLES,
    FL_T,
    FLIGHT_N,
    TOP_THICKNESS,
    flight_kernel,
    landing_flight,
    landing_kernel,
    packed_params,
    solid_gap,
)
from .table import (
    HALF_LENGTH,
    HALF_WIDTH,
    NET_HALF_WIDTH,
    NET_HEIGHT,
    TABLE_HEIGHT,
    ZONE_LENGTH,
    ZONE_WIDTH,
    on_table,
    zone_bounds,
    zone_centre,
    zone_margin,
    zone_of,
)

# The index constants I_MASS, I_RADIUS, ... of params.py, exported under the same names.
globals().update({name: getattr(_params, name) for name in INDEX_NAMES})

__all__ = [
    # parameters: the declaration, the typed structure, the packed layout
    'FIELDS', 'EFFECTS', 'FIELD', 'Field', 'Effect', 'ModelParams', 'load_model',
    'PACKED_FIELDS', 'INDEX', 'INDEX_NAMES', 'N_PACKED', 'SLOT_BOUNDS', 'EFFECT_FIELDS',
    'DRAG_SPEED_REF', 'LIFT_SPIN_RATIO_REF', 'IMPACT_SPEED_REF', 'SLIP_SPEED_REF',
    'EDGE_LENGTH_REF',
    *INDEX_NAMES,   # I_MASS, I_RADIUS, ...: slots of the packed array (params.py)
    # equations
    'flight_derivative', 'flight_jacobian', 'flight_acceleration', 'table_rebound',
    'table_rebound_inplace', 'table_restitution', 'edge_distance', 'edge_gradient',
    'racket_rebound',
    'racket_rebound_inplace',
    # integration
    'rk4_step', 'rk4_advance', 'rollout', 'rollout_kernel', 'landing_kernel', 'Event',
    'DEFAULT_STEP',
    # the one flight kernel with the table as a body (predict.py): its result row and kinds
    'flight_kernel', 'landing_flight', 'solid_gap', 'packed_params', 'TOP_THICKNESS',
    'FLIGHT_N', 'FL_KIND', 'FL_T', 'FL_S', 'FL_NET_T', 'FL_NET_Y', 'FL_NET_Z', 'FL_CROSS_T',
    'FL_CROSS_X', 'FL_CROSS_Y', 'FL_SAMPLES', 'CONTACT_KINDS', 'CONTACT_TOP', 'CONTACT_EDGE',
    'CONTACT_NET', 'CONTACT_POST', 'CONTACT_FLOOR', 'CONTACT_PLANE', 'CONTACT_TIMEOUT',
    'CONTACT_OFF',
    'ROLL_SPEED', 'STOP_AT_NET', 'STOP_AT_PLANE', 'EVENT_BOUNCE', 'EVENT_NET', 'EVENT_PLANE',
    'EVENT_FLOOR', 'EVENT_ROLL', 'EVENT_TIMEOUT', 'EVENT_NAMES',
    # table
    'HALF_LENGTH', 'HALF_WIDTH', 'NET_HEIGHT', 'NET_HALF_WIDTH', 'TABLE_HEIGHT',
    'ZONE_LENGTH', 'ZONE_WIDTH', 'on_table', 'zone_of', 'zone_centre', 'zone_bounds',
    'zone_margin',
]
