//! `cellcal identify`: identify the MDH errors from a measurement CSV (`--data`, its setup
//! header as defaults) or re-identify a stored campaign (`--store`, exactly as the campaign
//! did); print the summary, write the JSON contract and (`--report`) the HTML report.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};
use clap::ValueEnum;
use nalgebra::Vector3;

use cellcal::calibrate::{calibrate, BaseSource, CalibrationResult, IdentifyReport, Quality};
use cellcal::campaign::iso::is_iso_campaign;
use cellcal::campaign::report::campaign_facts;
use cellcal::campaign::stored::load_stored;
use cellcal::dataset::{
    parse_vec3, read_csv, read_text, CsvSetup, Observation, ReadError, Required,
};
use cellcal::identify::solver::{Options, DEFAULT_MAX_ITERATIONS};
use cellcal::identify::{IdentifyOptions, Nongeometric, ObsConfig, ObsModel, RobustLoss};
use cellcal::model::load_robot;
use cellcal::model::rotation::from_rotation_vector;
use cellcal::model::{RobotModel, SignedAxis};
use cellcal::report::html::{CampaignFacts, InputDigest, Provenance, ReportInput};
use cellcal::report::model_file::sha256_hex;
use cellcal::report::{corrected_model_toml, summary_text};
use cellcal::simulate::TrackerNoise;
use cellcal::units::human::local_time_zone;
use cellcal::wall_clock::now_unix_ms;

use super::stored::{campaign_id, open_store};
use super::{input, other, Failure};

/// Stage travel when neither the data nor a flag gives one (mm).
const DEFAULT_TRAVEL_MM: f64 = 10.0;

/// Observation model names on the command line.
#[derive(Clone, Copy, ValueEnum)]
enum ModelArg {
    Position,
    Np,
    Op,
    Full,
}

impl ModelArg {
    fn model(self) -> ObsModel {
        match self {
            ModelArg::Position => ObsModel::Position,
            ModelArg::Np => ObsModel::Np,
            ModelArg::Op => ObsModel::Op,
            ModelArg::Full => ObsModel::Full,
        }
    }
}

/// Robust loss names on the command line.
#[derive(Clone, Copy, ValueEnum)]
enum RobustArg {
    Huber,
    Cauchy,
}

/// Arguments of `cellcal identify`.
#[derive(clap::Args)]
pub struct IdentifyArgs {
    /// Robot model file (TOML); with --store it replaces the campaign's stored model.
    #[arg(long, required_unless_present = "store")]
    robot: Option<PathBuf>,
    /// Measurement CSV (its `# stage_axis`, `# tool_mm`, `# stage_travel_mm` header lines are
    /// the defaults; a flag that contradicts one is an error).
    #[arg(long, required_unless_present = "store", conflicts_with = "store")]
    data: Option<PathBuf>,
    /// Campaign store: re-identify a stored campaign with its stored configuration, robot
    /// model and setup (a flag that contradicts its setup is an error).
    #[arg(long)]
    store: Option<PathBuf>,
    /// Campaign id in --store (default: the latest).
    #[arg(long, requires = "store")]
    campaign: Option<i64>,
    /// Observation model (with --store default: the campaign's).
    #[arg(long, value_enum, required_unless_present = "store")]
    model: Option<ModelArg>,
    /// Stage axis in the flange frame: +x, -x, +y, -y, +z, -z or a measured vector X,Y,Z
    /// (normalised). Default: the data's setup, else +x for np and +y otherwise.
    #[arg(long, value_parser = SignedAxis::parse, allow_hyphen_values = true)]
    stage_axis: Option<SignedAxis>,
    /// Stage travel between P1 and P2 (mm). Default: the data's setup, else 10.
    #[arg(long)]
    stage_travel_mm: Option<f64>,
    /// Ball position in the flange frame, X,Y,Z (mm). Default: the data's setup, else the
    /// robot file's tool.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    tool_mm: Option<Vector3<f64>>,
    /// Identify the base transform (data in the tracker frame).
    #[arg(long)]
    identify_base: bool,
    /// Identify the ball position in the flange frame.
    #[arg(long)]
    identify_tool: bool,
    /// Down-weight gross outliers (default loss: Huber).
    #[arg(long, num_args = 0..=1, default_missing_value = "huber", value_enum)]
    robust: Option<RobustArg>,
    /// Weight each pose by the AT960 uncertainty model σ = (15 µm + 6 µm/m·range)/2, range
    /// from the tracker at X,Y,Z (mm, measurement frame; 0,0,0 when the data is in the tracker frame).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    tracker_weights: Option<Vector3<f64>>,
    /// Weight of direction rows (mm); default stage travel/√2.
    #[arg(long)]
    direction_weight_mm: Option<f64>,
    /// Also identify non-geometric joint terms (§10): `compliance`, `harmonics` or both
    /// (`compliance,harmonics`); the geometric model is fitted on the same data too and both
    /// are reported (`nongeometric_terms`, `metrics_geometric`).
    #[arg(long, value_name = "LIST")]
    nongeometric: Option<String>,
    /// Levenberg–Marquardt iteration limit (a result that hits it is reported NOT converged).
    #[arg(long, default_value_t = DEFAULT_MAX_ITERATIONS)]
    max_iterations: usize,
    #[command(flatten)]
    practical: super::practical::PracticalArgs,
    /// Write the JSON result here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the corrected model here: a robot TOML with the identified absolute values that
    /// every command takes as `--robot` (and `compensate --identified`).
    #[arg(long)]
    model_out: Option<PathBuf>,
    /// Write the calibration report here: one self-contained HTML file with plots (from
    /// --data, the sections that need a campaign store say so).
    #[arg(long)]
    report: Option<PathBuf>,
}

/// What the data source gives before the flags apply.
struct Source {
    /// Nominal model (robot file, or the stored campaign's with its setup applied).
    robot: RobotModel,
    /// Data-set rows.
    rows: Vec<Observation>,
    /// Setup values the flags must agree with.
    setup: CsvSetup,
    /// The source's own options (a stored campaign's), if any.
    campaign: Option<IdentifyOptions>,
    /// Names the setup's origin in messages (`the header of d.csv`, `campaign 3 in c.db`).
    origin: String,
    /// Names the rows in error messages.
    label: String,
    /// Where the data and the nominal model come from, for a corrected model's header (empty
    /// from a CSV without --model-out, which needs none).
    provenance: Vec<String>,
    /// The setup holds a registered base.
    registered_base: bool,
    /// What the report shows besides the identification (gathered only for --report).
    report: ReportContext,
}

/// The campaign's facts (from a store) and the inputs' digests, for the HTML report.
#[derive(Default)]
struct ReportContext {
    facts: Option<CampaignFacts>,
    inputs: Vec<InputDigest>,
}

/// Run `cellcal identify`.
pub fn run(a: IdentifyArgs) -> Result<(), Failure> {
    let mut source = match (&a.data, &a.store) {
        (Some(data), _) => csv_source(&a, data)?,
        (None, Some(store)) => store_source(&a, store)?,
        (None, None) => return Err(input(anyhow!("give --data CSV or --store FILE"))),
    };
    let label = source.label.clone();
    let provenance = source.provenance.clone();
    let registered = source.registered_base;
    let context = std::mem::take(&mut source.report);
    let (robot, opts, travel, rows) = resolve(&a, source)?;
    let base = BaseSource::of(opts.identify_base, registered);
    let (report, id) = calibrate(&robot, &rows, &opts, travel)
        .with_context(|| label.clone())
        .map_err(input)?;
    let mut result = CalibrationResult::of(report, &id, base);
    if a.report.is_some() {
        // the per-pose errors only for the report: a large data set does not pay for them
        result = result
            .with_residuals(&id, &rows, travel)
            .with_context(|| label.clone())
            .map_err(input)?;
    }
    let report = &result.report;
    print!("{}", summary_text(report));
    if let Some(path) = &a.json {
        write_file(path, &result.identify_json().map_err(other)?)?;
    }
    if let Some(path) = &a.model_out {
        let text = corrected_model_toml(&result, &robot, &provenance, base).map_err(other)?;
        write_file(path, &text)?;
    }
    if let Some(path) = &a.report {
        let provenance = Provenance::of_this_build(now_unix_ms(), context.inputs)
            .in_time_zone(local_time_zone());
        let title = format!("Calibration report: {label}");
        let mut html =
            ReportInput::of_result(&title, &label, &result, provenance).with_significance(&robot);
        html.campaign = context.facts;
        super::report::write_report(path, &html)?;
    }
    poor_is_exit_3(report, "the result")
}

/// Write `text` to `path` (exit 1 when it cannot).
pub(crate) fn write_file(path: &Path, text: &str) -> Result<(), Failure> {
    std::fs::write(path, text)
        .with_context(|| format!("{}: cannot write", path.display()))
        .map_err(other)
}

/// `NAME (sha256 HEX)` of a file read as `text`.
pub(crate) fn file_id(path: &Path, text: &str) -> String {
    format!(
        "{} (sha256 {})",
        path.display(),
        sha256_hex(text.as_bytes())
    )
}

/// The digest of the file at `path`, for the report (`what` names it).
fn file_digest(what: &str, path: &Path) -> Result<InputDigest, Failure> {
    let bytes = std::fs::read(path)
        .with_context(|| format!("{}: cannot read", path.display()))
        .map_err(input)?;
    Ok(InputDigest::of(what, &path.display().to_string(), &bytes))
}

/// Exit 3 when the verdict is `poor` (after the result was printed and written).
pub(crate) fn poor_is_exit_3(report: &IdentifyReport, what: &str) -> Result<(), Failure> {
    if report.quality != Quality::Poor {
        return Ok(());
    }
    let codes: Vec<&str> = report
        .warnings
        .iter()
        .filter(|w| w.severity == Quality::Poor)
        .map(|w| w.code.as_str())
        .collect();
    Err(Failure(
        3,
        anyhow!(
            "{what} is poor ({}): see the warnings at the top of the summary",
            codes.join(", ")
        ),
    ))
}

/// A CSV data set and its setup header.
fn csv_source(a: &IdentifyArgs, data: &Path) -> Result<Source, Failure> {
    let robot_path = a
        .robot
        .as_deref()
        .ok_or_else(|| input(anyhow!("--data needs --robot")))?;
    let robot = load_robot(robot_path).map_err(input)?;
    let model = a
        .model
        .ok_or_else(|| input(anyhow!("--data needs --model")))?
        .model();
    let label = data.display().to_string();
    let (setup, rows) = match read_csv(data, robot.dof(), Required::for_model(model)) {
        Ok(read) => read,
        Err(ReadError::Io(e)) => {
            let e = anyhow::Error::new(e).context(format!("{}: cannot read", data.display()));
            return Err(input(e));
        }
        Err(ReadError::Csv(e)) => return Err(input(anyhow::Error::new(e).context(label))),
    };
    // the files' digests, for a corrected model's header and the report only (the text is not
    // kept: read again)
    let text = || {
        read_text(data)
            .with_context(|| format!("{}: cannot read", data.display()))
            .map_err(input)
    };
    let provenance = match &a.model_out {
        None => Vec::new(),
        Some(_) => {
            let robot_text = std::fs::read_to_string(robot_path)
                .with_context(|| format!("{}: cannot read", robot_path.display()))
                .map_err(input)?;
            vec![
                format!("Data: {}", file_id(data, &text()?)),
                format!("Nominal model: {}", file_id(robot_path, &robot_text)),
            ]
        }
    };
    let mut report = ReportContext::default();
    if a.report.is_some() {
        report.inputs = vec![
            file_digest("robot model file", robot_path)?,
            InputDigest::of("measurement CSV", &label, text()?.as_bytes()),
        ];
    }
    Ok(Source {
        robot,
        rows,
        registered_base: setup.base_translation_mm.is_some()
            || setup.base_rotation_vector_rad.is_some(),
        setup,
        campaign: None,
        origin: format!("the header of {label}"),
        label,
        provenance,
        report,
    })
}

/// A stored campaign, rebuilt as the campaign identified it.
fn store_source(a: &IdentifyArgs, store: &Path) -> Result<Source, Failure> {
    let s = open_store(store)?;
    let id = campaign_id(&s, store, a.campaign)?;
    if is_iso_campaign(&s, id).map_err(other)? {
        return Err(input(anyhow!(
            "{}: campaign {id} is an ISO 9283 campaign: it is not identified; its figures are \
             `cellcal iso9283 --campaign {id}`",
            store.display()
        )));
    }
    let robot = a
        .robot
        .as_deref()
        .map(load_robot)
        .transpose()
        .map_err(input)?;
    let c = load_stored(&s, id, robot)
        .with_context(|| store.display().to_string())
        .map_err(input)?;
    let origin = format!("campaign {id} in {}", store.display());
    let mut provenance = vec![format!("Data: {origin}")];
    if let Some(path) = &a.robot {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))
            .map_err(input)?;
        provenance.push(format!("Nominal model: {}", file_id(path, &text)));
    } else {
        provenance.push("Nominal model: the campaign's stored robot model".to_owned());
    }
    let mut report = ReportContext::default();
    if a.report.is_some() {
        let (facts, mut inputs) = campaign_facts(&s, id)
            .with_context(|| store.display().to_string())
            .map_err(input)?;
        if let Some(r) = &a.robot {
            inputs.push(file_digest(
                "robot model file (--robot, replaces the stored one)",
                r,
            )?);
        }
        report = ReportContext {
            facts: Some(facts),
            inputs,
        };
    }
    Ok(Source {
        robot: c.nominal,
        rows: c.rows,
        registered_base: c.setup.base_translation_mm.is_some(),
        setup: c.setup,
        campaign: Some(c.opts),
        label: origin.clone(),
        origin,
        provenance,
        report,
    })
}

/// A flag and the source's setup value must agree; the agreed (or only) value. Equal within
/// 1e-9 (relative) counts as agreement, and then the source's value is kept bit for bit.
fn agree<T: Copy>(
    flag: (&str, Option<T>),
    setup: (&str, Option<T>),
    origin: &str,
    differ: impl Fn(&T, &T) -> bool,
    show: impl Fn(&T) -> String,
) -> Result<Option<T>, Failure> {
    match (flag.1, setup.1) {
        (Some(f), Some(s)) if differ(&f, &s) => Err(input(anyhow!(
            "{} {} contradicts `{} = {}` in {origin}: drop the flag (or change the source)",
            flag.0,
            show(&f),
            setup.0,
            show(&s)
        ))),
        (f, s) => Ok(s.or(f)),
    }
}

fn vectors_differ(a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
    (a - b).norm() > 1e-9 * b.norm().max(1.0)
}

fn show_vector(v: &Vector3<f64>) -> String {
    format!("{},{},{}", v.x, v.y, v.z)
}

/// The model, options and travel from the source and the flags.
fn resolve(
    a: &IdentifyArgs,
    source: Source,
) -> Result<(RobotModel, IdentifyOptions, f64, Vec<Observation>), Failure> {
    let Source {
        mut robot,
        rows,
        setup,
        campaign,
        origin,
        ..
    } = source;
    let model = match (a.model, &campaign) {
        (Some(m), _) => m.model(),
        (None, Some(c)) => c.obs.model,
        (None, None) => return Err(input(anyhow!("--model is required"))),
    };
    if let Some(t) = a.stage_travel_mm {
        if !(t.is_finite() && t > 0.0) {
            return Err(input(anyhow!(
                "--stage-travel-mm must be a positive number"
            )));
        }
    }
    let travel = agree(
        ("--stage-travel-mm", a.stage_travel_mm),
        ("stage_travel_mm", setup.stage_travel_mm),
        &origin,
        |f, s| (f - s).abs() > 1e-9 * s.abs().max(1.0),
        |v| v.to_string(),
    )?
    .unwrap_or(DEFAULT_TRAVEL_MM);
    let tool = agree(
        ("--tool-mm", a.tool_mm),
        ("tool_mm", setup.tool_mm),
        &origin,
        vectors_differ,
        show_vector,
    )?;
    if let Some(t) = tool {
        robot.tool = t;
    }
    let registered_base =
        setup.base_translation_mm.is_some() || setup.base_rotation_vector_rad.is_some();
    if let Some(t) = setup.base_translation_mm {
        robot.base_translation = t;
    }
    if let Some(r) = setup.base_rotation_vector_rad {
        robot.base_rotation = from_rotation_vector(&r);
    }
    let mut obs = ObsConfig::new(model, travel);
    if let Some(u) = agree(
        ("--stage-axis", a.stage_axis.map(|s| s.unit())),
        ("stage_axis", setup.stage_axis),
        &origin,
        vectors_differ,
        show_vector,
    )? {
        obs.stage_axis = u;
    }
    if let Some(w) = a.direction_weight_mm {
        if !(w.is_finite() && w >= 0.0) {
            return Err(input(anyhow!("--direction-weight-mm must be ≥ 0")));
        }
        obs.direction_weight_mm = w;
    }
    let opts = IdentifyOptions {
        obs,
        identify_base: a.identify_base || campaign.is_some_and(|c| c.identify_base),
        identify_tool: a.identify_tool || campaign.is_some_and(|c| c.identify_tool),
        registered_base,
        robust: a.robust.map(|r| match r {
            RobustArg::Huber => RobustLoss::Huber,
            RobustArg::Cauchy => RobustLoss::Cauchy,
        }),
        point_weights: a.tracker_weights.map(TrackerNoise::at960),
        solver: Options {
            max_iterations: a.max_iterations,
            ..Options::default()
        },
        practical: a
            .practical
            .bounds(a.tracker_weights.is_some())
            .map_err(input)?,
        // a stored campaign's terms and `nongeometric_keep`; --nongeometric replaces the families
        nongeometric: match (&a.nongeometric, campaign) {
            (None, c) => c.map(|c| c.nongeometric).unwrap_or_default(),
            (Some(list), c) => Nongeometric {
                keep: c.map(|c| c.nongeometric.keep).unwrap_or_default(),
                ..crate_nongeometric(list)?
            },
        },
    };
    if opts.nongeometric.compliance && robot.masses.is_empty() {
        return Err(input(anyhow!(
            "--nongeometric compliance: compliance multiplies the gravity torque of the robot's \
             masses, but the robot file has no [[masses]]: add them (docs/configuration.md) or \
             leave compliance out"
        )));
    }
    Ok((robot, opts, travel, rows))
}

/// `--nongeometric LIST` as the identification's term set (a bad name: exit 2 with the reason).
fn crate_nongeometric(list: &str) -> Result<Nongeometric, Failure> {
    let families = cellcal::model::TermFamily::parse_list(list)
        .map_err(|e| input(anyhow!("--nongeometric: {e}")))?;
    Ok(Nongeometric::of(&families))
}
