"""Typed configuration of the forest LiDAR simulator (one scenario = one `SimConfig`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class StandConfig:
    """Where the trees stand. `source`: 'generated', a CSV file `x,y,dbh_m[,height_m]`, or the
    name of a stand in the shared data folder (longleaf, spruces)."""

    source: str = "generated"
    crop_m: tuple[float, float, float, float] | None = None  # xmin, ymin, xmax, ymax (world)
    # Generated stands: a point process over [0, size_x] x [0, size_y].
    size_m: tuple[float, float] = (60.0, 60.0)
    process: str = "clustered"  # clustered (Thomas) | regular (jittered grid) | poisson
    density_per_ha: float = 350.0
    cluster_radius_m: float = 8.0
    trees_per_cluster: float = 6.0
    min_spacing_m: float = 1.5
    dbh_mean_m: float = 0.25
    dbh_std_m: float = 0.08
    dbh_min_m: float = 0.07
    dbh_max_m: float = 0.70
    # Heights when the stand has none: Naslund curve h = 1.3 + (d / (a + b d))^2, d in cm.
    height_a: float = 1.0
    height_b: float = 0.18
    height_noise_rel: float = 0.05


@dataclass
class TerrainConfig:
    relief_m: float = 0.5  # smooth relief, +- this many metres
    relief_wavelength_m: float = 60.0  # dominant horizontal scale of the relief
    roughness_m: float = 0.02  # standard deviation of the fine (cell-scale) roughness
    cell_m: float = 0.5
    margin_m: float = 40.0  # terrain extends this far beyond trees and path


@dataclass
class StemConfig:
    """Stem shapes (see sim::Stem). Ranges (lo, hi) are drawn uniformly per tree."""

    taper_m_per_m: float = 0.01  # stem diameter lost per metre of height
    max_lean_deg: float = 3.0
    # (a - b) / (a + b) of the section, drawn in [0, max]; ovality (d_max - d_min) / d_max is
    # about twice that (0.04: up to 7.7 %).
    max_ellipticity: float = 0.04
    bark_amplitude_m: float = 0.003
    buried_m: float = 0.3  # stems start below the ground so slopes show no gap
    irregularity: tuple[float, float] = (0.0, 0.03)  # relative amplitude of 2-3-5 lobes
    polygon_sides: tuple[int, int] = (0, 0)  # polygonal sections with this many sides (0: round)
    flare: tuple[float, float] = (0.1, 0.35)  # root flare: relative radius added at the ground
    flare_height_m: tuple[float, float] = (0.6, 1.2)  # the flare is gone above this height
    # Sweep: the axis bows sideways by up to this many metres per metre of tree height (at mid
    # height); swept stems are chains of straight segments of at most segment_m.
    max_sweep_m_per_m: float = 0.005
    segment_m: float = 3.5


@dataclass
class ClutterConfig:
    branches_per_tree: float = 4.0  # dead branches on the lower stem (Poisson mean)
    branch_length_m: tuple[float, float] = (0.3, 1.3)
    branch_radius_m: tuple[float, float] = (0.008, 0.025)
    branch_height_m: tuple[float, float] = (0.5, 6.0)  # and below the crown base
    crown_base_fraction: tuple[float, float] = (0.4, 0.6)  # of tree height
    crown_radius_fraction: float = 0.15  # crown radius / tree height
    crown_clumps: int = 6  # foliage ellipsoids per crown
    foliage_sigma_per_m: float = 1.2  # extinction in foliage (1/m)
    shrubs_per_ha: float = 150.0
    shrub_radius_m: tuple[float, float] = (0.4, 1.1)
    shrub_height_m: tuple[float, float] = (0.4, 1.5)
    shrub_sigma_per_m: float = 2.5
    logs_per_ha: float = 8.0
    log_length_m: tuple[float, float] = (3.0, 9.0)
    log_radius_m: tuple[float, float] = (0.08, 0.22)
    path_clearance_m: float = 1.2  # shrubs, logs and branches keep this far from the path
    # Also keep the path of this scenario clear, so that two scenarios (e.g. tls-plot and
    # mls-plot) build the very same world: each names the other.
    keep_clear_scenario: str | None = None


@dataclass
class SensorConfig:
    """The scanner. Its measurement model (range noise, dropouts) defaults per profile to the
    simulator's own table (forestslam.sim.sensor_model), not to the profile's nominal values the
    pipeline reads; any value set here overrides the table."""

    profile: str = "vlp16"  # a shipped profile name or a profile YAML file
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # mounting tilt on the vehicle
    range_noise_m: float | None = None  # standard deviation at normal incidence
    beam_divergence_mrad: float | None = None  # footprint spread on inclined surfaces
    dropout_rate: float | None = None  # everywhere
    grazing_cos: float | None = None  # below this |cos incidence| returns fade out
    far_fraction: float | None = None  # beyond this fraction of the maximum range too


@dataclass
class MaterialConfig:
    """Intensity of one material at normal incidence and the reference range: log-normal around
    `median` (sensor units 0..255), one draw per object and one per return."""

    median: float = 50.0
    sigma_return: float = 0.25
    sigma_object: float = 0.1
    incidence_exponent: float = 1.0


@dataclass
class IntensityConfig:
    """Per-material intensity with range fall-off and incidence dependence. Not derived from any
    pipeline threshold: bark and foliage overlap a little, as real returns do."""

    ground: MaterialConfig = field(default_factory=lambda: MaterialConfig(30.0, 0.3, 0.1, 0.5))
    bark: MaterialConfig = field(default_factory=lambda: MaterialConfig(45.0, 0.3, 0.15, 1.0))
    branch: MaterialConfig = field(default_factory=lambda: MaterialConfig(55.0, 0.3, 0.15, 1.0))
    foliage: MaterialConfig = field(default_factory=lambda: MaterialConfig(140.0, 0.3, 0.1, 0.0))
    shrub: MaterialConfig = field(default_factory=lambda: MaterialConfig(120.0, 0.3, 0.1, 0.0))
    deadwood: MaterialConfig = field(default_factory=lambda: MaterialConfig(70.0, 0.3, 0.15, 1.0))
    reference_range_m: float = 5.0
    range_exponent: float = 0.25  # intensity * (reference / range)^exponent beyond the reference
    near_range_m: float = 1.5  # below it, intensity falls linearly to half at 0 m


@dataclass
class MotionConfig:
    """path: loop | lawnmower | line | station (static at centre_xy) | a CSV file with header
    `x,y` (waypoints, world frame). One waypoint is a static station (tls profile: one scan)."""

    path: str = "loop"
    length_m: float = 150.0
    speed_mps: float = 1.0
    sensor_height_m: float = 1.0
    centre_xy: tuple[float, float] | None = None  # default: centre of the stand
    heading_deg: float = 0.0  # orientation of line / lawnmower / loop
    loop_aspect: float = 1.0  # loop = ellipse with this ratio of axes
    lane_spacing_m: float = 12.0  # lawnmower
    lane_length_m: float | None = None  # lawnmower; default 80 % of the stand extent
    stem_clearance_m: float = 1.5  # from the stem surface to the sensor path
    footprint_m: tuple[float, float] = (2.0, 1.6)  # wheelbase, track: roll/pitch from terrain
    vibration_deg: float = 0.3
    vibration_z_m: float = 0.01
    duration_s: float = 5.0  # static stations with a scanning (non-tls) profile
    start_time_s: float = 1700000000.0
    max_scans: int | None = None


@dataclass
class OutputConfig:
    format: str = "bag"  # bag (ROS1) | mcap (ROS2)
    topic: str = "/velodyne_points"
    frame_id: str = "velodyne"
    preview: bool = False


@dataclass
class SimConfig:
    name: str = "custom"
    seed: int = 0
    # World style: a (round-ish stems, bright crowns) or b (polygonal, flared, swept stems, dense
    # leaf-clump crowns, another intensity model); fills the keys a scenario leaves unset (see
    # forestslam.sim.styles). Every figure can then be printed on two independent worlds.
    style: str = "a"
    stand: StandConfig = field(default_factory=StandConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    stems: StemConfig = field(default_factory=StemConfig)
    clutter: ClutterConfig = field(default_factory=ClutterConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    intensity: IntensityConfig = field(default_factory=IntensityConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
