"""Ball model parameters: one typed structure, YAML in and out, packed for compiled kernels.

The nominal values are those of MODEL.md ("Constants"). The *effects* block holds the extra
physical mechanisms that identification may switch on (``tt-identify`` writes them to
``model.yaml``); each is zero (off) by default, so the nominal model is the paper's. The
integrator evaluates every effect through the same equations, so switching one on never
touches the integrator.
"""

import dataclasses
import math

import numpy as np
import yaml

# Reference points of the effects (fixed, so that the base coefficients keep their meaning).
DRAG_SPEED_REF = 6.0
"""Air speed at which C_D equals ``c_d`` when ``c_d_speed_slope`` is on, m/s."""
LIFT_SPIN_RATIO_REF = 0.3
"""Spin ratio r|w|/|v| at which C_M equals ``c_m`` when ``c_m_spin_ratio_slope`` is on."""
IMPACT_SPEED_REF = 3.0
"""Normal impact speed at which e_t equals ``e_t`` when ``e_t_speed_slope`` is on, m/s."""

# Index of each field in the packed array (order of PACKED_FIELDS; wind takes three slots).
PACKED_FIELDS = ('mass', 'radius', 'gravity', 'air_density', 'area', 'c_d', 'c_m', 'e_t', 'mu',
                 'e_r', 'k_p', 'spin_decay', 'wind_x', 'wind_y', 'wind_z', 'c_d_speed_slope',
                 'c_m_spin_ratio_slope', 'e_t_speed_slope', 'mu_spin_slope',
                 'c_d_spin_ratio_slope')
(I_MASS, I_RADIUS, I_GRAVITY, I_RHO, I_AREA, I_CD, I_CM, I_ET, I_MU, I_ER, I_KP, I_SPIN_DECAY,
 I_WIND_X, I_WIND_Y, I_WIND_Z, I_CD_SLOPE, I_CM_SLOPE, I_ET_SLOPE, I_MU_SLOPE,
 I_CD_SPIN_SLOPE) = range(20)
N_PACKED = len(PACKED_FIELDS)

EFFECT_FIELDS = ('spin_decay', 'wind', 'c_d_speed_slope', 'c_m_spin_ratio_slope',
                 'e_t_speed_slope', 'mu_spin_slope', 'c_d_spin_ratio_slope')


@dataclasses.dataclass
class ModelParams:
    """Parameters of the ball model (SI units; spin in rad/s)."""

    mass: float = 2.7e-3
    """Ball mass m, kg."""
    radius: float = 0.020
    """Ball radius r, m."""
    gravity: float = 9.8
    """Magnitude of gravity g (acting along -z), m/s^2."""
    air_density: float = 1.184
    """Air density rho, kg/m^3."""
    area: float = 12.5e-4
    """Projected area A, m^2."""
    c_d: float = 0.54
    """Drag coefficient C_D."""
    c_m: float = 0.069
    """Magnus (lift) coefficient C_M of eq. 8."""
    e_t: float = 0.93
    """Table coefficient of restitution."""
    mu: float = 0.25
    """Ball-table dynamic friction coefficient."""
    e_r: float = 0.81
    """Racket rubber coefficient of restitution."""
    k_p: float = 1.9e-3
    """Rubber tangential stiffness k_p, kg/s."""

    # Effects (all off at zero).
    spin_decay: float = 0.0
    """Spin decay rate in flight: dw/dt = -spin_decay w, 1/s."""
    wind: tuple = (0.0, 0.0, 0.0)
    """Steady air velocity (draft), table frame, m/s; drag and lift act on v - wind."""
    c_d_speed_slope: float = 0.0
    """Speed-dependent drag: C_D = c_d + slope (|v - wind| - DRAG_SPEED_REF), s/m."""
    c_m_spin_ratio_slope: float = 0.0
    """Spin-ratio-dependent lift: C_M = c_m + slope (r|w|/|v - wind| - LIFT_SPIN_RATIO_REF)."""
    e_t_speed_slope: float = 0.0
    """Impact-speed-dependent restitution: e_t(v_z) = e_t + slope (|v_z| - IMPACT_SPEED_REF),
    s/m."""
    mu_spin_slope: float = 0.0
    """Spin-dependent table friction: mu(w) = mu + slope |w|, s/rad."""
    c_d_spin_ratio_slope: float = 0.0
    """Spin-dependent drag: C_D += slope (r|w|/|v - wind| - LIFT_SPIN_RATIO_REF)."""

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
    def inertia(self):
        """Moment of inertia of a thin spherical shell, (2/3) m r^2, kg m^2."""
        return 2.0 / 3.0 * self.mass * self.radius ** 2

    def packed(self):
        """The parameters as a float64 array indexed by the ``I_*`` constants."""
        values = []
        for name in PACKED_FIELDS:
            if name.startswith('wind_'):
                values.append(self.wind['xyz'.index(name[-1])])
            else:
                values.append(getattr(self, name))
        return np.array(values, dtype=np.float64)

    @classmethod
    def from_packed(cls, array):
        """Inverse of :meth:`packed`."""
        array = np.asarray(array, dtype=float)
        kwargs = {name: float(array[i]) for i, name in enumerate(PACKED_FIELDS)
                  if not name.startswith('wind_')}
        kwargs['wind'] = tuple(float(w) for w in array[I_WIND_X:I_WIND_Z + 1])
        return cls(**kwargs)

    def replace(self, **changes):
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def active_effects(self):
        """Names of the effects that are switched on (non-zero)."""
        active = []
        for name in EFFECT_FIELDS:
            value = getattr(self, name)
            if any(value) if isinstance(value, tuple) else value != 0.0:
                active.append(name)
        return active

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
        """Build from :meth:`to_dict` output (or a flat dict); unknown keys are an error."""
        if not isinstance(data, dict):
            raise ValueError('model file must hold a mapping')
        flat = {}
        for key, value in data.items():
            if key in ('ball', 'effects'):
                if not isinstance(value, dict):
                    raise ValueError(f"model file: '{key}' must be a mapping")
                flat.update(value)
            elif key in ('meta', 'selected_effects'):
                continue
            else:
                flat[key] = value
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(flat) - names)
        if unknown:
            raise ValueError(f'model file: unknown parameter(s) {", ".join(unknown)}')
        try:
            return cls(**{k: tuple(v) if k == 'wind' else float(v) for k, v in flat.items()})
        except (TypeError, ValueError) as exc:
            raise ValueError(f'model file: {exc}') from None

    def save(self, path, meta=None):
        """Write ``model.yaml`` (with an optional ``meta`` mapping, e.g. provenance)."""
        data = self.to_dict()
        if meta:
            data = {'meta': meta, **data}
        with open(path, 'w') as f:
            yaml.safe_dump(data, f, sort_keys=False)

    @classmethod
    def load(cls, path):
        """Read ``model.yaml``; raises ValueError naming the file on bad content."""
        try:
            with open(path) as f:
                data = yaml.safe_load(f)
        except OSError as exc:
            raise ValueError(f'{path}: cannot read model file: {exc.strerror}') from None
        except yaml.YAMLError as exc:
            raise ValueError(f'{path}: not valid YAML: {str(exc).splitlines()[0]}') from None
        try:
            return cls.from_dict(data)
        except ValueError as exc:
            raise ValueError(f'{path}: {exc}') from None


def load_model(path=None):
    """The model of ``path`` (a model.yaml), or the nominal model when ``path`` is empty."""
    return ModelParams.load(path) if path else ModelParams()
