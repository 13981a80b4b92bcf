//! `filmback cache list | show CAMERA [--plot FILE.png] | reset CAMERA`: the per-body
//! response cache.

use std::path::PathBuf;
use std::process::ExitCode;

use filmback::daemon::cache::{
    CachedResponse, DISSENTS_TO_REPLACE, MEASURED_SOURCE, MeasuredCurve, PooledBracket,
    RECOVERED_SOURCE, ResponseCache,
};
use filmback::response::{pool, stops_apart};

use super::calibrate::plot;

/// Arguments of `filmback cache`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// State folder of the daemon.
    #[arg(long, value_name = "DIR", default_value = ".filmback", global = true)]
    state: PathBuf,
    #[command(subcommand)]
    action: Action,
}

#[derive(Debug, clap::Subcommand)]
enum Action {
    /// One line per cached camera body.
    List,
    /// A body's curve g(B) at B = 0, 0.1, …, 1 per channel (CAMERA: name or part of it).
    Show {
        /// Camera name as `list` prints it, or a unique part of it.
        camera: String,
        /// Also draw g per channel into this PNG (the g panel of `calibrate --plot`).
        #[arg(long, value_name = "FILE.png")]
        plot: Option<PathBuf>,
    },
    /// Forget a body's curve; the next good bracket starts it afresh.
    Reset {
        /// Camera name as `list` prints it, or a unique part of it.
        camera: String,
    },
}

/// Runs the action.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let cache = ResponseCache::new(&args.state);
    match args.action {
        Action::List => {
            let entries = cache.list()?;
            if entries.is_empty() {
                println!("no cached responses in {}", args.state.display());
            }
            for e in entries {
                match e {
                    Ok(c) => println!(
                        "{}\t{} brackets\t{}\t{} channel(s){}",
                        c.camera,
                        c.brackets,
                        c.min_confidence().map_or_else(
                            || "confidence unknown".to_string(),
                            |v| format!("pool of {}, confidence {v:.2}", c.pool.len())
                        ),
                        c.response.channels(),
                        c.measured.as_ref().map_or(String::new(), |m| format!(
                            "\tmeasured from raw ({} capture(s))",
                            m.captures
                        ))
                    ),
                    Err(e) => println!("unusable entry: {e}"),
                }
            }
        }
        Action::Show { camera, plot } => {
            let c = cache.find(&camera)?;
            if let Some(path) = &plot {
                plot::write_response(path, &c.response, &plot_title(&c))?;
            }
            println!("camera    {}", c.camera);
            let file = cache
                .file_of(&c.camera)
                .unwrap_or_else(|| cache.path_for(&c.camera));
            println!("file      {}", file.display());
            println!("source    {RECOVERED_SOURCE}");
            println!("brackets  {} folded in", c.brackets);
            println!(
                "pooled    {} (the curve is one fit over their tone pairs)",
                c.pool.len()
            );
            println!("confidence {}", confidences(&c.confidence));
            println!("updated   {} (Unix seconds)", c.updated);
            println!("samples   {} per channel", c.response.samples(0).len());
            if let Some(path) = &plot {
                println!("plot      {}", path.display());
            }
            print!("B     ");
            for ch in 0..c.response.channels() {
                print!("  g_{ch}(B)  ");
            }
            println!();
            for i in 0..=10 {
                let b = f64::from(i) / 10.0;
                print!("{b:.1}   ");
                for ch in 0..c.response.channels() {
                    print!("  {:.5}  ", c.response.eval(ch, b));
                }
                println!();
            }
            show_pool(&c);
            if let Some(m) = &c.measured {
                show_measured(&c, m);
            }
        }
        Action::Reset { camera } => {
            let who = cache.reset(&camera)?;
            println!("forgot the cached response of {who}");
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Per channel, `R 0.81, G 0.77, B 0.70`; `unknown` when not stored.
fn confidences(c: &[f64]) -> String {
    if c.is_empty() {
        return "unknown (an entry from before pooling)".to_string();
    }
    let names: &[&str] = if c.len() == 1 {
        &["Y"]
    } else {
        &["R", "G", "B"]
    };
    names
        .iter()
        .zip(c)
        .map(|(n, v)| format!("{n} {v:.2}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The pooled and dissenting brackets of `cache show`, each with how far the body's
/// curve and its own fit are from its tone pairs.
fn show_pool(c: &CachedResponse) {
    let row = |b: &PooledBracket| {
        println!(
            "  {:<24} {:>12}  {:>6} {:>6.3} {:>6.3}",
            b.name,
            b.at,
            format!("{:.2}", b.own_confidence),
            b.own_misfit,
            pool::agreement(&b.evidence, &c.response)
        );
    };
    let header = || {
        println!(
            "  {:<24} {:>12}  {:>6} {:>6} {:>6}",
            "bracket", "at (Unix s)", "conf.", "own", "body"
        );
    };
    if !c.pool.is_empty() {
        println!();
        println!(
            "pooled brackets, oldest first (own fit's confidence; RMS stops by which its own fit and the body's curve miss its tone pairs):"
        );
        header();
        c.pool.iter().for_each(row);
    }
    if !c.dissent.is_empty() {
        println!();
        println!(
            "contradicting brackets kept aside ({} of {DISSENTS_TO_REPLACE} in a row that agree with one another replace the pool):",
            c.dissent.len()
        );
        header();
        c.dissent.iter().for_each(row);
    }
}

/// The measured curve of `cache show` and how far the recovered one is from it, in stops
/// per channel.
fn show_measured(c: &CachedResponse, m: &MeasuredCurve) {
    println!();
    println!("measured  {MEASURED_SOURCE}");
    println!("captures  {}", m.captures);
    println!("updated   {} (Unix seconds)", m.updated);
    let coverage: Vec<String> = m
        .coverage
        .iter()
        .map(|f| format!("{:.0} %", 100.0 * f))
        .collect();
    println!(
        "coverage  {} of codes 1..254 per channel",
        coverage.join(", ")
    );
    print!("B     ");
    for ch in 0..m.response.channels() {
        print!("  g_{ch}(B)  ");
    }
    println!();
    for i in 0..=10 {
        let b = f64::from(i) / 10.0;
        print!("{b:.1}   ");
        for ch in 0..m.response.channels() {
            print!("  {:.5}  ", m.response.eval(ch, b));
        }
        println!();
    }
    if c.brackets == 0 {
        println!("recovered curve: none yet (no bracket has been fitted)");
        return;
    }
    println!("recovered against measured, |log2(g_recovered/g_measured)| over codes 8..254:");
    for (ch, (rms, max)) in stops_apart(&c.response, &m.response).iter().enumerate() {
        println!("  channel {ch}: RMS {rms:.3} stops, max {max:.3} stops");
    }
}

/// The figure title of `cache show --plot`: camera, brackets pooled, and confidence.
fn plot_title(c: &CachedResponse) -> String {
    let brackets = if c.pool.len() == 1 {
        "BRACKET"
    } else {
        "BRACKETS"
    };
    let confidence = c
        .min_confidence()
        .map_or_else(String::new, |v| format!(", CONFIDENCE {v:.2}"));
    format!(
        "CACHED G(B) OF {}: {} {brackets} POOLED{confidence}",
        c.camera,
        c.pool.len()
    )
}
