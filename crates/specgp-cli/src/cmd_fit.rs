//! `specgp fit` and `specgp latent`: fit the latent space of a dataset and show it.

use std::path::PathBuf;
use std::time::Duration;

use crate::console::quantity;
use anyhow::Context;
use gplvm::{FitParams, Model, OptimizerKind};
use indicatif::{ProgressBar, ProgressStyle};

/// Arguments of `specgp fit`.
#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// Dataset store (`.sbrdf`).
    data: PathBuf,
    /// Output model file (TOML).
    #[arg(long)]
    out: PathBuf,
    /// Fit configuration (TOML, e.g. `configs/fit/paper.toml`); flags below override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Latent dimension q [default: 5, or the --config file's].
    #[arg(long)]
    latent_dim: Option<usize>,
    /// Optimiser: hooke-jeeves (the paper) or lbfgs [default: lbfgs].
    #[arg(long)]
    optimizer: Option<OptimizerKind>,
    /// RBF length-scale l [default: 1].
    // Values may start with '-' (then refused by the fit's own check, not by clap with advice
    // to write `-- -1`).
    #[arg(long, allow_hyphen_values = true)]
    lengthscale: Option<f64>,
    /// Noise mu [default: 0.0001].
    #[arg(long, allow_hyphen_values = true)]
    noise: Option<f64>,
    /// Learn amplitude and noise with the latent points (the length-scale stays: the latent
    /// points' own scale makes it redundant, docs/CONVENTIONS.md).
    #[arg(long)]
    learn_hyperparameters: bool,
    /// Data transform: raw, log or log:OFFSET [default: log, i.e. log:0.01].
    #[arg(long)]
    transform: Option<String>,
    /// Extra optimisations from perturbed starts [default: 0].
    #[arg(long)]
    restarts: Option<usize>,
    /// Seed of the restart perturbations [default: 0].
    #[arg(long)]
    seed: Option<u64>,
    /// Cap on L-BFGS iterations (`max_iterations`; a fit that reaches it is not converged and
    /// says so) [default: 5000].
    #[arg(long)]
    max_iterations: Option<u64>,
    /// Cap on Hooke-Jeeves objective evaluations (`max_evaluations`) [default: 200000].
    #[arg(long)]
    max_evaluations: Option<usize>,
}

/// Runs `specgp fit`.
pub fn fit(args: &FitArgs) -> anyhow::Result<()> {
    let config_file = args.config.as_deref();
    crate::paths::ensure_output_is_not_an_input(
        &args.out,
        &[args.data.as_path()]
            .into_iter()
            .chain(config_file)
            .collect::<Vec<_>>(),
    )?;
    // `info` and the SOURCE syntax `MODEL.toml@X,Y` recognise models by their extension.
    crate::paths::ensure_extension(&args.out, "toml", "a model file")?;
    // The model records the dataset's path as TOML text: say so now, not after the fit.
    if args.data.to_str().is_none() {
        anyhow::bail!(
            "{}: the dataset path is not valid UTF-8, and the model file records it as text \
             (rename the store or link it under a UTF-8 name)",
            args.data.display()
        );
    }
    let mut params = match &args.config {
        Some(path) => FitParams::from_toml_file(path)?,
        None => FitParams::default(),
    };
    if let Some(q) = args.latent_dim {
        params.latent_dim = q;
    }
    if let Some(o) = args.optimizer {
        params.optimizer = o;
    }
    if let Some(l) = args.lengthscale {
        params.lengthscale = l;
    }
    if let Some(mu) = args.noise {
        params.noise = mu;
    }
    if args.learn_hyperparameters {
        params.learn_hyperparameters = true;
    }
    if let Some(t) = &args.transform {
        params.transform = t.clone();
    }
    if let Some(r) = args.restarts {
        params.restarts = r;
    }
    if let Some(s) = args.seed {
        params.seed = s;
    }
    if let Some(n) = args.max_iterations {
        params.max_iterations = n;
    }
    if let Some(n) = args.max_evaluations {
        params.max_evaluations = n;
    }
    refuse_ignored_caps(args, &params)?;
    if let (Some(seed), 0) = (args.seed, params.restarts) {
        // A warning, not a refusal: scripts may pass a seed to every fit (docs/CLI.md).
        tracing::warn!(
            "--seed {seed} has no effect without restarts: the fit starts from the PCA \
             solution, which is deterministic (add --restarts N to use the seed)"
        );
    }
    let config = params.check().with_context(|| match &args.config {
        Some(path) => format!(
            "fit configuration {} (with the command line's flags)",
            path.display()
        ),
        None => "fit configuration (the command line's flags)".to_owned(),
    })?;
    let spinner = ProgressBar::new_spinner();
    spinner.set_style(
        ProgressStyle::with_template("fit [{elapsed_precise}] {spinner} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    spinner.set_message(format!(
        "Gram pass over {} and {} optimisation",
        args.data.display(),
        config.params.optimizer
    ));
    spinner.enable_steady_tick(Duration::from_millis(120));
    let model = gplvm::fit_store(&args.data, &config);
    spinner.finish_and_clear();
    let model = model.with_context(|| format!("fitting {}", args.data.display()))?;
    model.save(&args.out)?;
    let f = &model.fit;
    errln!(
        "fitted {}, q = {}, transform {}: log-likelihood {:.6e} (PCA start {:.6e}), \
         |grad| {:.2e}, {} evaluations, Gram pass {:.2} s, optimiser {:.3} s -> {}",
        quantity(model.materials.len(), "material"),
        model.latent_dim,
        model.transform,
        f.log_likelihood,
        f.initial_log_likelihood,
        f.gradient_norm,
        f.evaluations,
        f.gram_seconds,
        f.optimize_seconds,
        args.out.display()
    );
    Ok(())
}

/// Refuses a cap flag that the chosen optimiser ignores (README: options that would be ignored
/// are refused before any work): `--max-evaluations` caps Hooke-Jeeves only (L-BFGS counts
/// iterations, each of one or more evaluations by its line search) and `--max-iterations`
/// caps L-BFGS only. `params` are the merged configuration; only the command line's flags are
/// checked (a `--config` file may hold both caps, for either optimiser).
fn refuse_ignored_caps(args: &FitArgs, params: &FitParams) -> anyhow::Result<()> {
    let chosen_by = || match (&args.optimizer, &args.config) {
        (Some(_), _) => "--optimizer".to_owned(),
        (None, Some(path)) => format!("the --config file {}", path.display()),
        (None, None) => "the default".to_owned(),
    };
    match params.optimizer {
        OptimizerKind::Lbfgs => {
            if let Some(n) = args.max_evaluations {
                anyhow::bail!(
                    "--max-evaluations {n} caps the Hooke-Jeeves optimiser, but the fit uses \
                     lbfgs ({}), which stops at --max-iterations (or choose --optimizer \
                     hooke-jeeves)",
                    chosen_by()
                );
            }
        }
        OptimizerKind::HookeJeeves => {
            if let Some(n) = args.max_iterations {
                anyhow::bail!(
                    "--max-iterations {n} caps the L-BFGS optimiser, but the fit uses \
                     hooke-jeeves ({}), which stops at --max-evaluations (or choose \
                     --optimizer lbfgs)",
                    chosen_by()
                );
            }
        }
    }
    Ok(())
}

/// Arguments of `specgp latent`.
#[derive(Debug, clap::Args)]
pub struct LatentArgs {
    /// Model file (TOML).
    model: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

/// Runs `specgp latent`.
pub fn latent(args: &LatentArgs) -> anyhow::Result<()> {
    let model = Model::load(&args.model)?;
    if args.json {
        let doc = serde_json::json!({
            "log_likelihood": model.fit.log_likelihood,
            "latent_dim": model.latent_dim,
            "materials": model.materials.iter().map(|m| serde_json::json!({
                "name": m.name, "coords": m.coords
            })).collect::<Vec<_>>(),
        });
        let text = serde_json::to_string_pretty(&doc).context("serialising JSON")?;
        outln!("{text}");
    } else {
        outln!("# log-likelihood {:.10e}", model.fit.log_likelihood);
        for m in &model.materials {
            let coords: Vec<String> = m.coords.iter().map(|c| format!("{c:+.6}")).collect();
            outln!("{:<40} {}", m.name, coords.join(" "));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[derive(clap::Parser)]
    struct Wrapper {
        #[command(flatten)]
        fit: FitArgs,
    }

    /// The defaults the help text states are `FitParams::default()`'s (the flags are optional so
    /// that a --config file can set them, so clap cannot show them itself).
    #[test]
    fn help_states_the_real_defaults() {
        let cmd = Wrapper::command();
        let help = |name: &str| -> String {
            cmd.get_arguments()
                .find(|a| a.get_id() == name)
                .and_then(|a| a.get_help())
                .map(|h| h.to_string())
                .unwrap()
        };
        let d = FitParams::default();
        let want = [
            ("latent_dim", format!("[default: {},", d.latent_dim)),
            ("optimizer", format!("[default: {}]", d.optimizer)),
            ("lengthscale", format!("[default: {}]", d.lengthscale)),
            ("noise", format!("[default: {}]", d.noise)),
            ("transform", format!("[default: {},", d.transform)),
            ("restarts", format!("[default: {}]", d.restarts)),
            ("seed", format!("[default: {}]", d.seed)),
            ("max_iterations", format!("[default: {}]", d.max_iterations)),
            (
                "max_evaluations",
                format!("[default: {}]", d.max_evaluations),
            ),
        ];
        for (name, text) in want {
            assert!(
                help(name).contains(&text),
                "{name}: {} lacks {text}",
                help(name)
            );
        }
    }
}
