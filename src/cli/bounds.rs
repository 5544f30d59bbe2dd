//! `cbfreach bounds <network.safetensors> --lower a,b --upper c,d`: sound affine and interval
//! bounds of a network over one box.

use std::path::PathBuf;

use cbfreach::bounds::{network_bounds, AffineBounds, BoundMethod};
use cbfreach::network::Mlp;
use serde::Serialize;

use super::{parse_point, CliResult};

/// Arguments of `cbfreach bounds`.
#[derive(clap::Args)]
pub struct BoundsArgs {
    /// The network (safetensors, as written by `cbfreach train`).
    pub network: PathBuf,
    /// Lower corner of the box, comma-separated (e.g. `-1,0.5`).
    #[arg(long, value_name = "X1,X2,...", allow_hyphen_values = true)]
    pub lower: String,
    /// Upper corner of the box, comma-separated.
    #[arg(long, value_name = "X1,X2,...", allow_hyphen_values = true)]
    pub upper: String,
    /// How the network is bounded.
    #[arg(long, value_enum, default_value_t = BoundMethod::Crown)]
    pub method: BoundMethod,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The JSON output: `A_lower x + b_lower ≤ N(x) ≤ A_upper x + b_upper` and
/// `lower ≤ N(x) ≤ upper` on the box.
#[derive(Serialize)]
struct BoundsJson<'a> {
    method: &'static str,
    lower: &'a [f64],
    upper: &'a [f64],
    #[serde(rename = "A_lower")]
    a_lower: Vec<&'a [f64]>,
    b_lower: &'a [f64],
    #[serde(rename = "A_upper")]
    a_upper: Vec<&'a [f64]>,
    b_upper: &'a [f64],
}

/// Checks the box against the network, naming the offending option.
fn check_box(net: &Mlp, lower: &[f64], upper: &[f64]) -> Result<(), String> {
    let n = net.input_dim();
    for (option, x) in [("--lower", lower), ("--upper", upper)] {
        if x.len() != n {
            return Err(format!(
                "{option}: {} coordinates given, but the network's input dimension is {n}",
                x.len()
            ));
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "{option}: coordinate {} is {}, not a finite number",
                i + 1,
                x[i]
            ));
        }
    }
    if let Some(i) = (0..n).find(|&i| lower[i] > upper[i]) {
        return Err(format!(
            "--lower/--upper: coordinate {} has lower {} > upper {} (inverted box)",
            i + 1,
            lower[i],
            upper[i]
        ));
    }
    Ok(())
}

/// Runs the command.
pub fn run(args: &BoundsArgs) -> CliResult {
    let net = Mlp::load_safetensors(&args.network)?;
    let lower = parse_point("--lower", &args.lower)?;
    let upper = parse_point("--upper", &args.upper)?;
    check_box(&net, &lower, &upper)?;
    let b = network_bounds(&net, &lower, &upper, args.method)?;
    if args.json {
        println!("{}", serde_json::to_string(&to_json(args.method, &b))?);
    } else {
        print_table(&net, args, &lower, &upper, &b);
    }
    Ok(())
}

fn to_json(method: BoundMethod, b: &AffineBounds) -> BoundsJson<'_> {
    BoundsJson {
        method: method.name(),
        lower: &b.lower,
        upper: &b.upper,
        a_lower: (0..b.n_out).map(|i| b.a_lower_row(i)).collect(),
        b_lower: &b.b_lower,
        a_upper: (0..b.n_out).map(|i| b.a_upper_row(i)).collect(),
        b_upper: &b.b_upper,
    }
}

fn print_table(net: &Mlp, args: &BoundsArgs, lower: &[f64], upper: &[f64], b: &AffineBounds) {
    let fmt_row = |a: &[f64]| {
        a.iter()
            .map(|v| format!("{v:>11.4e}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!(
        "{}: {} network, {} bounds over the box {}:",
        args.network.display(),
        net.architecture(),
        args.method.name(),
        lower
            .iter()
            .zip(upper)
            .map(|(l, u)| format!("[{l}, {u}]"))
            .collect::<Vec<_>>()
            .join(" × ")
    );
    println!("  A_lower·x + b_lower ≤ N(x) ≤ A_upper·x + b_upper,  lower ≤ N(x) ≤ upper");
    println!(
        "  {:>6}  {:>12}  {:>12}  {:>10}  {:>11}  {:>11}  A_lower | A_upper",
        "output", "lower", "upper", "width", "b_lower", "b_upper"
    );
    for i in 0..b.n_out {
        println!(
            "  {:>6}  {:>12.6e}  {:>12.6e}  {:>10.3e}  {:>11.4e}  {:>11.4e}  {} | {}",
            i + 1,
            b.lower[i],
            b.upper[i],
            b.upper[i] - b.lower[i],
            b.b_lower[i],
            b.b_upper[i],
            fmt_row(b.a_lower_row(i)),
            fmt_row(b.a_upper_row(i))
        );
    }
}
