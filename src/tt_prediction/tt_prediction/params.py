"""Ball model parameters: one declaration, from which the typed structure, the YAML file, the
packed layout of the compiled kernels and identification's effect library are generated.

:data:`FIELDS` declares every parameter once: name, default (MODEL.md "Constants"), unit,
plausible range and, for the *effects*, the effect it belongs to. :data:`EFFECTS` declares
the effects: the extra physical mechanisms that identification may switch on (``tt-identify``
writes them to ``model.yaml``). Each effect coefficient is zero (off) by default, so the
default model is the paper's. The integrator evaluates every effect through the same
equations (model.py), so switching one on never touches the integrator.

Adding an effect: docs/DEVELOPING.md, "Adding a model effect".
"""

import dataclasses
import hashlib
import math
import os
import shutil
import time

import numba
import numpy as np
from tt_ros.errors import one_line_reason
from tt_ros.yamlfile import load_yaml
import yaml

STALE_CACHE_AGE = 86400.0
"""A kernel cache of other sources untouched for this long is removed, s."""
KERNEL_SOURCES = ('params.py', 'model.py', 'integrate.py', 'table.py', 'predict.py')
"""The files of the ball model's compiled kernels, whose content keys the kernel cache."""


def _use_versioned_kernel_cache():
    """Key numba's on-disk cache by the content of the ball model's sources.

    numba's ``cache=True`` checks the time stamp of the file of the cached function only: a
    kernel of integrate.py (or of tt_strike) that inlines model.py's equations would keep the
    old physics after an edit of model.py or of the packed layout. The cache therefore lives
    in ``__pycache__/numba-<hash of KERNEL_SOURCES>`` (others untouched for a day are
    removed: a process still running on older sources keeps its cache), unless
    NUMBA_CACHE_DIR is set or that directory cannot be written (numba's default then).
    """
    if numba.config.CACHE_DIR:
        return
    here = os.path.dirname(os.path.abspath(__file__))
    digest = hashlib.sha1()
    for name in KERNEL_SOURCES:
        try:
            with open(os.path.join(here, name), 'rb') as f:
                digest.update(f.read())
        except OSError:
            continue
    root = os.path.join(here, '__pycache__')
    path = os.path.join(root, 'numba-' + digest.hexdigest()[:12])
    try:
        os.makedirs(path, exist_ok=True)
        if not os.access(path, os.W_OK):
            return
    except OSError:
        return
    for old in os.listdir(root):       # stale caches of older sources, not in use any more
        old = os.path.join(root, old)
        try:
            stale = time.time() - os.path.getmtime(old) > STALE_CACHE_AGE
        except OSError:
            continue
        if os.path.basename(old).startswith('numba-') and old != path and stale:
            shutil.rmtree(old, ignore_errors=True)
    numba.config.CACHE_DIR = path


_use_versioned_kernel_cache()

# Reference points of the effects (fixed, so that the base coefficients keep their meaning).
DRAG_SPEED_REF = 6.0
"""Air speed at which C_D equals ``c_d`` when ``c_d_speed_slope`` is on, m/s."""
LIFT_SPIN_RATIO_REF = 0.3
"""Spin ratio r|w|/|v| at which C_M equals ``c_m`` when ``c_m_spin_ratio_slope`` is on."""
IMPACT_SPEED_REF = 3.0
"""Normal impact speed at which e_t equals ``e_t`` when ``e_t_speed_slope`` is on, m/s."""
SLIP_SPEED_REF = 4.0
"""Tangential contact speed at which mu equals ``mu`` when ``mu_slip_slope`` is on, m/s."""
EDGE_LENGTH_REF = 0.1
"""Distance from the table's edge over which ``e_t_edge`` fades by 1/e, m."""


@dataclasses.dataclass(frozen=True)
class Field:
    """Declaration of one model parameter.

    Attributes
    ----------
    name : str
        Field name (in ModelParams and model.yaml).
    default : float or tuple
        Default value: MODEL.md's nominal value; 0 (off) for an effect coefficient. A tuple
        declares a vector (one packed slot per component, ``<name>_x`` ...).
    unit : str
        SI unit of the value ('1' for a dimensionless one).
    bounds : tuple
        Plausible range (lo, hi) of the value (of each component of a vector). A model file
        outside it is refused; identification fits within it.
    doc : str
        What the parameter is, with the equation it enters.
    effect : str
        Name of the effect (in :data:`EFFECTS`) the coefficient belongs to; '' for the
        paper's parameters.
    """

    name: str
    default: object
    unit: str
    bounds: tuple
    doc: str
    effect: str = ''

    @property
    def slots(self):
        """Names of the packed slots of this field (one per component)."""
        if isinstance(self.default, tuple):
            return tuple(f'{self.name}_{c}' for c in 'xyz'[:len(self.default)])
        return (self.name,)


@dataclasses.dataclass(frozen=True)
class Effect:
    """Declaration of one model effect: a mechanism the paper's model leaves out.

    Attributes
    ----------
    name : str
        Effect name (as reported by tt-identify and in model.yaml's selected_effects).
    slots : tuple of str
        Packed slots identification frees to fit the effect (in identification's library
        also a global of the measurement model: spin_scale).
    mechanism : str
        The equation of the mechanism, in words.
    needs : str
        Data it needs to be tested: 'bounces' (a table effect) or '' (any flight); in
        identification's library (tt_prediction.identify.effects) also 'spin' (measured
        spin) and 'bounces_no_spin' (bounces and no measured spin).
    """

    name: str
    slots: tuple
    mechanism: str
    needs: str = ''


FIELDS = (
    # The paper's parameters (MODEL.md, "Constants").
    Field('mass', 2.7e-3, 'kg', (1.5e-3, 5e-3), 'Ball mass m.'),
    Field('radius', 0.020, 'm', (0.015, 0.025), 'Ball radius r.'),
    Field('gravity', 9.8, 'm/s^2', (8.0, 12.0),
          'Gravity g along -z (its magnitude on a level table; see gravity_x).'),
    Field('air_density', 1.184, 'kg/m^3', (0.5, 1.5), 'Air density rho.'),
    Field('area', 12.5e-4, 'm^2', (7e-4, 2e-3), 'Projected area A (eq. 8).'),
    Field('c_d', 0.54, '1', (0.1, 2.0), 'Drag coefficient C_D (eq. 8).'),
    Field('c_m', 0.069, '1', (0.0, 0.5), 'Magnus (lift) coefficient C_M (eq. 8).'),
    Field('e_t', 0.93, '1', (0.5, 1.0), 'Table coefficient of restitution (eqs. 1-6).'),
    Field('mu', 0.25, '1', (0.0, 1.0), 'Ball-table dynamic friction coefficient (eqs. 1-6).'),
    Field('e_r', 0.81, '1', (0.3, 1.0), 'Racket rubber coefficient of restitution (eq. 7).'),
    Field('k_p', 1.9e-3, 'kg', (0.0, 5e-3),
          'Rubber tangential stiffness k_p (eq. 7; K_v = k_p / m is dimensionless).'),
    # Effects (all off at zero).
    Field('spin_decay', 0.0, '1/s', (0.0, 10.0),
          'Spin decay rate in flight: dw/dt = -spin_decay w.', effect='spin_decay'),
    Field('wind', (0.0, 0.0, 0.0), 'm/s', (-5.0, 5.0),
          'Steady air velocity (draft), table frame: drag and lift act on v - wind (eq. 8).',
          effect='wind'),
    Field('c_d_speed_slope', 0.0, 's/m', (-0.2, 0.2),
          'Speed-dependent drag: C_D = c_d + slope (|v - wind| - DRAG_SPEED_REF).',
          effect='drag_reynolds'),
    Field('c_m_spin_ratio_slope', 0.0, '1', (-1.0, 1.0),
          'Spin-ratio-dependent lift: C_M = c_m + slope (r|w|/|v - wind| - '
          'LIFT_SPIN_RATIO_REF).', effect='lift_spin_ratio'),
    Field('e_t_speed_slope', 0.0, 's/m', (-0.3, 0.3),
          'Impact-speed-dependent restitution: e_t(v_z) = e_t + slope (|v_z| - '
          'IMPACT_SPEED_REF).', effect='table_restitution_speed'),
    Field('mu_spin_slope', 0.0, 's/rad', (-2e-3, 2e-3),
          'Spin-dependent table friction: mu(w) = mu + slope |w|.',
          effect='table_friction_spin'),
    Field('c_d_spin_ratio_slope', 0.0, '1', (-1.0, 1.0),
          'Spin-dependent drag: C_D += slope (r|w|/|v - wind| - LIFT_SPIN_RATIO_REF).',
          effect='drag_spin'),
    Field('e_t_tangential', 0.0, '1', (0.0, 0.9),
          'Tangential compliance of the ball on the table (its tangential restitution): a '
          "ball that grips leaves with its contact velocity reversed, v_T' = -e_t_tangential "
          "v_T, instead of rolling (v_T' = 0, eqs. 1-6); the grip regime starts at the slip "
          'ratio 2/5 (1 + e_t_tangential).', effect='table_compliance'),
    Field('e_t_spin_slope', 0.0, 's/m', (-0.03, 0.03),
          'Spin-dependent restitution: e_t += slope r|w| (eqs. 1-6).',
          effect='table_restitution_spin'),
    Field('mu_slip_slope', 0.0, 's/m', (-0.05, 0.05),
          'Slip-speed-dependent friction: mu += slope (|v_T| - SLIP_SPEED_REF), v_T the '
          'tangential contact velocity before the bounce (eqs. 1-6).',
          effect='table_friction_slip'),
    Field('gravity_x', 0.0, 'm/s^2', (-1.0, 1.0),
          "Gravity along the table's x axis: a table (or the frame it is measured in) not "
          'level, a = (gravity_x, gravity_y, -gravity) + ... in eq. 8 (0.17 m/s^2 a degree).',
          effect='gravity_tilt'),
    Field('gravity_y', 0.0, 'm/s^2', (-1.0, 1.0),
          "Gravity along the table's y axis (see gravity_x).", effect='gravity_tilt'),
    Field('e_t_edge', 0.0, '1', (-0.3, 0.3),
          'Place-dependent restitution, the table top livelier or deader near its edges (the '
          "frame under it): e_t += e_t_edge exp(-d / EDGE_LENGTH_REF), d the bounce's "
          'distance to the nearest edge of the playing surface (eqs. 1-6).',
          effect='table_restitution_edge'),
)
"""The declaration of every model parameter, in packed order."""

EFFECTS = (
    Effect('spin_decay', ('spin_decay',),
           'air friction slows the spin in flight: dw/dt = -spin_decay w (1/s)'),
    Effect('wind', ('wind_x', 'wind_y'),
           'a steady horizontal air draft (m/s): drag and lift act on v - wind'),
    Effect('drag_reynolds', ('c_d_speed_slope',),
           'drag coefficient varies with air speed (Reynolds number): '
           'C_D = c_d + slope (|v| - 6 m/s)'),
    Effect('drag_spin', ('c_d_spin_ratio_slope',),
           'drag coefficient varies with the spin ratio (the spinning boundary layer): '
           'C_D = c_d + slope (r|w|/|v| - 0.3)'),
    Effect('lift_spin_ratio', ('c_m_spin_ratio_slope',),
           'Magnus coefficient varies with the spin ratio: C_M = c_m + slope (r|w|/|v| - 0.3)'),
    Effect('table_restitution_speed', ('e_t_speed_slope',),
           'table restitution falls with impact speed: e_t = e_t + slope (|v_z| - 3 m/s)',
           needs='bounces'),
    Effect('table_restitution_spin', ('e_t_spin_slope',),
           'table restitution varies with spin: e_t = e_t + slope r|w|', needs='bounces'),
    Effect('table_friction_spin', ('mu_spin_slope',),
           'table friction varies with spin: mu = mu + slope |w|', needs='bounces'),
    Effect('table_friction_slip', ('mu_slip_slope',),
           'table friction varies with slip speed: mu = mu + slope (|v_T| - 4 m/s)',
           needs='bounces'),
    Effect('table_compliance', ('e_t_tangential',),
           'the ball grips the table and springs back (tangential compliance, like the '
           "rubber's k_p): the contact velocity reverses, v_T' = -e_x v_T, spin overshoots",
           needs='bounces'),
    Effect('gravity_tilt', ('gravity_x', 'gravity_y'),
           'the table is not level: gravity has a part along it, (g_x, g_y) m/s^2 in the '
           "table frame (0.17 m/s^2 a degree); a constant acceleration, where a draft's "
           'grows with the speed'),
    Effect('table_restitution_edge', ('e_t_edge',),
           'table restitution depends on where the ball lands: the top is livelier or deader '
           f'near its edges, e_t = e_t + e_t_edge exp(-d / {EDGE_LENGTH_REF:g} m), d the '
           'distance to the nearest edge', needs='bounces'),
)
"""The declaration of the model effects (identification adds measurement effects)."""

FIELD = {f.name: f for f in FIELDS}
"""Declaration of each field by name."""
PACKED_FIELDS = tuple(slot for f in FIELDS for slot in f.slots)
"""Name of each slot of the packed array, in order."""
INDEX = {slot: i for i, slot in enumerate(PACKED_FIELDS)}
"""Index of each packed slot by name."""
N_PACKED = len(PACKED_FIELDS)
EFFECT_FIELDS = tuple(f.name for f in FIELDS if f.effect)
"""Names of the effect coefficients (model.yaml's ``effects`` block)."""
SLOT_BOUNDS = {slot: f.bounds for f in FIELDS for slot in f.slots}
"""Plausible range of each packed slot (identification's fit range)."""

# Indices of the packed array used by the compiled kernels (generated, not numbered).
I_MASS = INDEX['mass']
I_RADIUS = INDEX['radius']
I_GRAVITY = INDEX['gravity']
I_RHO = INDEX['air_density']
I_AREA = INDEX['area']
I_CD = INDEX['c_d']
I_CM = INDEX['c_m']
I_ET = INDEX['e_t']
I_MU = INDEX['mu']
I_ER = INDEX['e_r']
I_KP = INDEX['k_p']
I_SPIN_DECAY = INDEX['spin_decay']
I_WIND_X = INDEX['wind_x']
I_WIND_Y = INDEX['wind_y']
I_WIND_Z = INDEX['wind_z']
I_CD_SLOPE = INDEX['c_d_speed_slope']
I_CM_SLOPE = INDEX['c_m_spin_ratio_slope']
I_ET_SLOPE = INDEX['e_t_speed_slope']
I_MU_SLOPE = INDEX['mu_spin_slope']
I_CD_SPIN_SLOPE = INDEX['c_d_spin_ratio_slope']
I_ET_TANGENTIAL = INDEX['e_t_tangential']
I_ET_SPIN_SLOPE = INDEX['e_t_spin_slope']
I_MU_SLIP_SLOPE = INDEX['mu_slip_slope']
I_GRAVITY_X = INDEX['gravity_x']
I_GRAVITY_Y = INDEX['gravity_y']
I_ET_EDGE = INDEX['e_t_edge']
INDEX_NAMES = tuple(name for name in dir() if name.startswith('I_'))
"""The names of the index constants above (tt_prediction.ball exports them)."""


def _check_declaration():
    """The declaration is consistent: effects and fields refer to each other."""
    effects = {e.name: e for e in EFFECTS}
    for f in FIELDS:
        if not f.effect:
            continue
        if f.effect not in effects:
            raise AssertionError(f'field {f.name}: undeclared effect {f.effect}')
        values = f.default if isinstance(f.default, tuple) else (f.default,)
        if any(v != 0.0 for v in values):
            raise AssertionError(f'effect field {f.name}: default must be 0 (off)')
    for e in EFFECTS:
        for slot in e.slots:
            if slot not in INDEX or FIELD[_field_of(slot)].effect != e.name:
                raise AssertionError(f'effect {e.name}: slot {slot} is not its field')


def _field_of(slot):
    """Name of the field that holds a packed slot."""
    for f in FIELDS:
        if slot in f.slots:
            return f.name
    raise KeyError(slot)


_check_declaration()


def _fmt(value):
    return f'{value:g}'


def _declared(cls):
    """Add the declared fields (FIELDS) to ``cls`` and make it a dataclass."""
    cls.__annotations__ = {f.name: (tuple if isinstance(f.default, tuple) else float)
                           for f in FIELDS}
    for f in FIELDS:
        setattr(cls, f.name, f.default)
    lines = ['', 'Attributes', '----------']
    for f in FIELDS:
        kind = 'tuple of 3 floats' if isinstance(f.default, tuple) else 'float'
        lines += [f'{f.name} : {kind}', f'    {f.doc} Unit {f.unit}; default {f.default}.']
    cls.__doc__ = cls.__doc__.rstrip() + '\n' + '\n'.join(lines) + '\n'
    return dataclasses.dataclass(cls)


@_declared
class ModelParams:
    """The ball model's parameters (SI units; spin in rad/s), one field per :data:`FIELDS`
    entry; the effect coefficients are 0 (off) by default (the Attributes below are
    generated from the declaration)."""

    def __post_init__(self):
        self.wind = tuple(float(w) for w in self.wind)
        if len(self.wind) != 3:
            raise ValueError('wind must have 3 components')
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            values = value if isinstance(value, tuple) else (value,)
            if not all(math.isfinite(float(v)) for v in values):
                raise ValueError(f'model parameter {field.name} is not finite: {value}')
        for name in ('mass', 'radius', 'gravity', 'air_density', 'area'):
            if getattr(self, name) <= 0.0:
                raise ValueError(f'model parameter {name} must be positive')

    @property
    def gravity_vector(self):
        """Gravity in the table frame, (gravity_x, gravity_y, -gravity), m/s^2 (eq. 8)."""
        return np.array([self.gravity_x, self.gravity_y, -self.gravity])

    @property
    def inertia(self):
        """Moment of inertia of a thin spherical shell, (2/3) m r^2, kg m^2."""
        return 2.0 / 3.0 * self.mass * self.radius ** 2

    def packed(self):
        """The parameters as a float64 array (N_PACKED,) indexed by the ``I_*`` constants
        (slot names :data:`PACKED_FIELDS`)."""
        values = []
        for f in FIELDS:
            value = getattr(self, f.name)
            values.extend(value if isinstance(value, tuple) else (value,))
        return np.array(values, dtype=np.float64)

    @classmethod
    def from_packed(cls, array):
        """Inverse of :meth:`packed`."""
        array = np.asarray(array, dtype=float)
        kwargs = {}
        for f in FIELDS:
            values = tuple(float(array[INDEX[s]]) for s in f.slots)
            kwargs[f.name] = values if isinstance(f.default, tuple) else values[0]
        return cls(**kwargs)

    def replace(self, **changes):
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def active_effects(self):
        """Names of the effect coefficients that are switched on (non-zero)."""
        active = []
        for name in EFFECT_FIELDS:
            value = getattr(self, name)
            if any(value) if isinstance(value, tuple) else value != 0.0:
                active.append(name)
        return active

    def implausible(self):
        """The first value outside its declared plausible range, as one line naming the field
        (and what it is), or '' when all are plausible."""
        for f in FIELDS:
            value = getattr(self, f.name)
            lo, hi = f.bounds
            for v in (value if isinstance(value, tuple) else (value,)):
                if not lo <= v <= hi:
                    what = f.doc.split(':')[0].split(' (')[0].rstrip('.')
                    unit = '' if f.unit == '1' else f' {f.unit}'
                    return (f'{f.name} = {_fmt(v)}{unit} is outside the plausible range '
                            f'{_fmt(lo)}..{_fmt(hi)}{unit} ({what})')
        # Eq. 7 with I = (2/3) m r^2 multiplies the contact point's tangential velocity by
        # 1 - 2.5 K_v: beyond K_v = 0.8 the rubber would give the ball energy.
        if self.k_p > 0.8 * self.mass:
            return (f'k_p = {_fmt(self.k_p)} kg is above 0.8 m = {_fmt(0.8 * self.mass)} kg: '
                    f'eq. 7 would multiply the contact velocity by 1 - 2.5 k_p / m = '
                    f'{1.0 - 2.5 * self.k_p / self.mass:.2f}, giving the ball energy')
        return ''

    def to_dict(self):
        """Plain dict: ``{'ball': {...}, 'effects': {...}}`` as written to model.yaml."""
        ball, effects = {}, {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            value = list(value) if isinstance(value, tuple) else float(value)
            (effects if field.name in EFFECT_FIELDS else ball)[field.name] = value
        return {'ball': ball, 'effects': effects}

    @classmethod
    def from_dict(cls, data):
        """Build from :meth:`to_dict` output (or a flat dict); raises ValueError (one line)
        for unknown keys, a parameter in the other block than its own, a value that is not
        a number (a boolean or a string is not one; wind: a list of three), values outside
        the plausible ranges of :data:`FIELDS`, and a ball parameter left out (each is
        required: a missing c_d was the nominal one without a word). An effect left out is
        0, not applied."""
        if not isinstance(data, dict):
            raise ValueError('model file must hold a mapping')
        flat = {}
        for key, value in data.items():
            if key in ('ball', 'effects'):
                if not isinstance(value, dict):
                    raise ValueError(f"model file: '{key}' must be a mapping")
                for name in value:
                    if name in FIELD and (name in EFFECT_FIELDS) != (key == 'effects'):
                        raise ValueError(f"model file: {name} belongs under "
                                         f"'{'effects' if key == 'ball' else 'ball'}', not "
                                         f"'{key}'")
                for name, v in value.items():
                    flat[_once(flat, name, key)] = v
            elif key in ('meta', 'selected_effects'):
                continue
            else:
                flat[_once(flat, key, None)] = value
        unknown = sorted(set(flat) - set(FIELD), key=str)   # keys of any YAML type
        unknown = [str(k) for k in unknown]
        if unknown:
            raise ValueError(f'model file: unknown parameter(s) {", ".join(unknown)}')
        kwargs = {}
        for key, value in flat.items():
            kwargs[key] = _model_number(key, value)
        try:
            params = cls(**kwargs)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'model file: {exc}') from None
        problem = params.implausible()
        if problem:
            raise ValueError(f'model file: {problem}')
        missing = [f.name for f in FIELDS if not f.effect and f.name not in flat]
        if missing:
            raise ValueError(f'model file: ball parameter(s) missing: {", ".join(missing)} '
                             '(each is required; tt-identify writes them all)')
        return params

    def save(self, path, meta=None):
        """Write ``model.yaml`` (with an optional ``meta`` mapping, e.g. provenance)."""
        data = self.to_dict()
        if meta:
            data = {'meta': meta, **data}
        with open(path, 'w') as f:
            yaml.safe_dump(data, f, sort_keys=False)

    @classmethod
    def load(cls, path):
        """Read ``model.yaml``; raises ValueError (one line naming the file and the field)
        on bad content."""
        try:
            with open(path) as f:
                data = load_yaml(f)
        except OSError as exc:
            raise ValueError(f'{path}: cannot read model file: {exc.strerror}') from None
        except yaml.YAMLError as exc:
            raise ValueError(f'{path}: not valid YAML: {one_line_reason(exc)}') from None
        try:
            return cls.from_dict(data)
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from None


def _once(flat, name, block):
    """``name``, checked not to be in ``flat`` already: a model file's parameter given in its
    block and again at the top level ran with whichever came last (a walk-through, 6 Dec
    2026)."""
    if name in flat:
        where = f"under '{block}'" if block else 'at the top level'
        raise ValueError(f'model file: {name} is given twice (again {where})')
    return name


def _model_number(key, value):
    """A model file's ``value`` of ``key`` as a float (a tuple of three for wind);
    ValueError naming it for anything else (YAML's true, a string, a list elsewhere)."""
    def number(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError
        return float(v)
    try:
        if key == 'wind':
            if not isinstance(value, (list, tuple)):
                raise ValueError
            return tuple(number(v) for v in value)
        return number(value)
    except ValueError:
        kind = 'a list of three numbers' if key == 'wind' else 'a number'
        raise ValueError(f'model file: {key} must be {kind}, got {value!r}') from None


def load_model(path=None):
    """The model of a model.yaml, or the nominal model.

    Parameters
    ----------
    path : str or None
        model.yaml to read; empty or None for the nominal (paper's) model.

    Returns
    -------
    ModelParams

    Raises
    ------
    ValueError
        One line naming the file and what is wrong (unreadable, bad YAML, unknown key,
        non-number, value outside its declared plausible range).
    """
    return ModelParams.load(path) if path else ModelParams()
