//! `filmback cache list | show CAMERA [--plot FILE.png] | reset CAMERA`: the per-body
//! response cache.

use std::path::PathBuf;
use std::process::ExitCode;

use filmback::daemon::cache::{
    CachedResponse, MEASURED_SOURCE, MeasuredCurve, RECOVERED_SOURCE, ResponseCache,
};
use filmback::response::stops_apart;

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
                        "{}\t{} brackets\tweight {:.2}\t{} channel(s){}",
                        c.camera,
                        c.brackets,
                        c.weight,
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
            println!("file      {}", cache.path_for(&c.camera).display());
            println!("source    {RECOVERED_SOURCE}");
            println!("brackets  {}", c.brackets);
            println!("weight    {:.3}", c.weight);
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

/// The figure title of `cache show --plot`: camera, brackets folded in, and weight.
fn plot_title(c: &CachedResponse) -> String {
    let brackets = if c.brackets == 1 {
        "BRACKET"
    } else {
        "BRACKETS"
    };
    format!(
        "CACHED G(B) OF {}: {} {brackets}, WEIGHT {:.2}",
        c.camera, c.brackets, c.weight
    )
}
