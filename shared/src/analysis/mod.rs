//! Trajectory analysis (docs/science.md#preprocessing to
//! docs/science.md#subject-data): preprocessing and spline resampling of
//! centre-of-mass paths, aggregation statistics, subject costs and rankings,
//! the subject CSV format, and the result document served by the CLI and the
//! coordinator. Pure functions: no I/O, no logging, no panics on input.
//! Degenerate input yields a typed [`AnalysisError`], never a NaN.

pub mod aggregate;
pub mod calibration;
pub mod costs;
pub mod digest;
pub mod holdout;
pub mod inputs;
pub mod methods;
pub mod observables;
pub mod points;
pub mod posterior;
pub mod preprocess;
pub mod refine;
pub mod report;
pub mod solvers;
pub mod spline;
pub mod stats;
pub mod subjects;
pub mod timing;

pub use aggregate::{ReportOptions, TrialSummary, WeightSummary};
pub use calibration::{
    calibrate, calibrate_sets, Calibration, CoverageRow, SetRule, COVERAGE_LEVELS,
};
pub use costs::{
    area_difference, argmax_first, argmin_first, correlation, pearson, softmax, subject_costs,
    SubjectCosts, CORR_FIRST, CORR_LAST, K_AREA, K_CORR,
};
pub use digest::{digest_grid, DigestedTrial, PointDigests, TopEpisode, TrialDigest};
pub use holdout::{
    hold_out_recovery, hold_out_table, CaseMethod, HoldOutCase, HoldOutReport, HoldOutRow,
    HoldOutTally, SolverHoldOut,
};
pub use inputs::{EpisodeRecord, TrialInput, WeightInput};
pub use methods::{CredibleSummary, Method, MethodResult, MethodResults};
pub use observables::{Observables, PathFeatures};
pub use points::{point_label, point_label_with};
pub use posterior::{
    highest_probability_set, prior_weights, shortest_interval_set, CredibleSet, GridPosterior,
    OutOfModel, PosteriorError, PosteriorOptions, Prior,
};
pub use preprocess::{
    path_area, preprocess, resample_path, PreprocessedPath, ResampledPath, MIN_POINTS,
    RESAMPLE_POINTS,
};
pub use refine::SubjectRefinement;
pub use report::{
    build_report, build_report_from, build_report_with, identifiability_from, report_to_csv,
    Identifiability, ResultDocument, SubjectSummary, ANALYSIS_VERSION, IDENTIFIABILITY_MIN_TRIALS,
    REPORT_CSV_HEADER,
};
pub use solvers::{OptimumAtPoint, SolverAtPoint, SolverKind, SolverTag, DEFAULT_SOLVER};
pub use spline::NaturalCubicSpline;
pub use subjects::{parse_subjects_csv, subjects_to_csv, SubjectPath, SUBJECT_CSV_HEADER};
pub use timing::{stand_up_timing, Timing, ONSET_FRACTION, STANDING_FRACTION};

/// Errors of the analysis functions. Each variant carries the
/// offending value so that the message alone locates the problem.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnalysisError {
    /// Fewer samples than the operation needs.
    #[error("need at least {min} points, got {n}")]
    TooFewPoints {
        /// Number of points given.
        n: usize,
        /// Minimum number required.
        min: usize,
    },
    /// Two sequences that must pair up element by element differ in length.
    #[error("{what}: expected {expected} values, found {found}")]
    LengthMismatch {
        /// Which sequence is the wrong length.
        what: &'static str,
        /// Required length.
        expected: usize,
        /// Actual length.
        found: usize,
    },
    /// An input value is NaN or infinite.
    #[error("value at index {index} is not finite")]
    NonFinite {
        /// 0-based index of the first offending sample.
        index: usize,
    },
    /// The path ends where it starts, so it has no direction to rotate to the
    /// vertical and no rise to normalize by (docs/science.md#preprocessing, steps 2-3).
    #[error(
        "path ends where it starts (start-to-end distance {rise}); it has no rise to normalize by"
    )]
    ZeroRise {
        /// Start-to-end distance in input units (0 or below rounding level).
        rise: f64,
    },
    /// After dropping consecutive repeated points too few distinct points
    /// remain for a spline fit.
    #[error("only {distinct} distinct consecutive points among {total}; need at least 4")]
    RepeatedPoints {
        /// Points left after dropping consecutive repeats.
        distinct: usize,
        /// Points given.
        total: usize,
    },
    /// Spline knots must be strictly increasing.
    #[error("spline knot {index} is not greater than the knot before it")]
    KnotsNotIncreasing {
        /// 0-based index of the first knot that does not increase.
        index: usize,
    },
    /// Finite inputs so extreme (near the f64 range) that the arithmetic
    /// overflowed.
    #[error("computation overflowed: input values too extreme")]
    Overflow,
    /// An operation that needs at least one item got none.
    #[error("no data")]
    Empty,
    /// A report option is out of range.
    #[error("invalid option {name} = {value}")]
    InvalidOption {
        /// Option name.
        name: &'static str,
        /// Offending value.
        value: f64,
    },
    /// Malformed subject CSV (docs/science.md#subject-data).
    #[error("line {line}: {msg}")]
    Csv {
        /// 1-based line number in the file.
        line: usize,
        /// What is wrong there.
        msg: String,
    },
}
