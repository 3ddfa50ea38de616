//! Fit configuration: parsed from TOML into an unchecked form, then validated by [`FitParams::check`].
//!
//! `configs/fit/paper.toml` reproduces the paper (q = 2, l = 1, mu = 1e-4, unit amplitude, PCA
//! start, Hooke-Jeeves, raw values); the defaults here are the measured best configuration.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::transform::Transform;

/// Which optimiser moves the latent points (and hyperparameters).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OptimizerKind {
    /// Hooke-Jeeves direct search, as in the paper.
    HookeJeeves,
    /// L-BFGS on the analytic gradient.
    Lbfgs,
}

impl std::str::FromStr for OptimizerKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "hooke-jeeves" => Ok(Self::HookeJeeves),
            "lbfgs" => Ok(Self::Lbfgs),
            other => Err(Error::InvalidConfig {
                field: "optimizer",
                value: format!("{other:?}"),
                expected: "hooke-jeeves or lbfgs".into(),
            }),
        }
    }
}

impl std::fmt::Display for OptimizerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::HookeJeeves => "hooke-jeeves",
            Self::Lbfgs => "lbfgs",
        })
    }
}

/// How the data are scaled against the kernel amplitude before fitting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DataScaling {
    /// Divide the centred data by their RMS, so the average variance per dimension is 1 and a
    /// unit kernel amplitude is meaningful.
    UnitVariance,
    /// Use the transformed values as they are.
    None,
}

/// How the PCA start is scaled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum InitScaling {
    /// Scale all latent axes together so the first has unit standard deviation (keeps the
    /// PCA aspect ratio).
    Isotropic,
    /// Standardise every latent axis to unit standard deviation.
    PerAxis,
    /// Raw PCA scores of the scaled data.
    None,
    /// The isotropic start multiplied by the factor that maximises the likelihood (a 1-D
    /// search over 10^-3..10^3 before the optimiser starts): with a fixed length-scale the
    /// latent scale decides how correlated the materials look to the kernel.
    Likelihood,
}

/// Upper bound of [`FitParams::latent_dim`] (and of a model file's latent dimension).
pub const MAX_LATENT_DIM: usize = 64;

/// Upper bound of [`FitParams::restarts`]: each restart is a whole optimisation.
pub const MAX_RESTARTS: usize = 1000;

/// Fit parameters as written in a TOML file or on the command line, before validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FitParams {
    /// Latent dimension q >= 1.
    pub latent_dim: usize,
    /// Optimiser.
    pub optimizer: OptimizerKind,
    /// Data transform: `raw`, `log` or `log:OFFSET`.
    pub transform: String,
    /// Scaling of the data against the kernel amplitude.
    pub data_scaling: DataScaling,
    /// RBF amplitude s (the kernel variance is s^2).
    pub amplitude: f64,
    /// RBF length-scale l.
    pub lengthscale: f64,
    /// Noise mu (K = K_rbf + mu I).
    pub noise: f64,
    /// Learn s and mu with the latent points (type-II maximum likelihood); l stays fixed, as
    /// the latent points' own scale makes it redundant ([`crate::fit::LEARNT`]).
    pub learn_hyperparameters: bool,
    /// With `learn_hyperparameters`: the learnt noise stays above this floor (on the scaled
    /// data; `0` for none). Without it, data a noise-free GP can interpolate drive mu to ~1e-16
    /// and cond(K) to ~1e12 (raw synthetic data), where the gradient loses its accuracy.
    pub min_noise: f64,
    /// Standard-normal prior on the latent points.
    pub prior: bool,
    /// Scaling of the PCA start.
    pub init_scaling: InitScaling,
    /// Extra optimisations from perturbed PCA starts; the best likelihood wins (at most
    /// [`MAX_RESTARTS`]).
    pub restarts: usize,
    /// Seed of the restart perturbations.
    pub seed: u64,
    /// Iteration cap of L-BFGS. The default, 5000, is over twice what the log fits of the
    /// built-in synthetic sets need (1075-2132 iterations on grids 16,16,32 to 32,32,64, seeds
    /// 0-3, BENCHMARKS.md "gplvm", session 41): the default fit of the default `specgp synth`
    /// store took 2111, and stopped at the former cap of 2000 with a warning.
    pub max_iterations: u64,
    /// Evaluation cap of Hooke-Jeeves.
    pub max_evaluations: usize,
    /// L-BFGS stops when the gradient norm of the per-value objective -L/(N D) falls below this.
    pub gradient_tolerance: f64,
    /// L-BFGS stops when the per-value objective -L/(N D) changes by less than this in a step.
    pub cost_tolerance: f64,
    /// Initial step of Hooke-Jeeves.
    pub initial_step: f64,
    /// Final step of Hooke-Jeeves.
    pub min_step: f64,
}

impl Default for FitParams {
    fn default() -> Self {
        Self {
            latent_dim: 5,
            optimizer: OptimizerKind::Lbfgs,
            transform: "log".into(),
            data_scaling: DataScaling::UnitVariance,
            amplitude: 1.0,
            lengthscale: 1.0,
            noise: 1e-4,
            learn_hyperparameters: false,
            min_noise: 1e-6,
            prior: true,
            init_scaling: InitScaling::Likelihood,
            restarts: 0,
            seed: 0,
            max_iterations: 5_000,
            max_evaluations: 200_000,
            gradient_tolerance: 1e-7,
            cost_tolerance: 1e-11,
            initial_step: 0.1,
            min_step: 1e-6,
        }
    }
}

/// Validated fit configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct FitConfig {
    /// The validated parameters.
    pub params: FitParams,
    /// The parsed transform.
    pub transform: Transform,
}

impl FitParams {
    /// Reads parameters from a TOML file; unknown keys are errors.
    pub fn from_toml_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::File {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        toml::from_str(&text).map_err(|e| Error::File {
            path: path.to_owned(),
            reason: e.to_string(),
        })
    }

    /// Validates every value.
    pub fn check(self) -> Result<FitConfig> {
        let bad = |field: &'static str, value: &dyn std::fmt::Display, expected: String| {
            Err(Error::InvalidConfig {
                field,
                value: value.to_string(),
                expected,
            })
        };
        if self.latent_dim == 0 || self.latent_dim > MAX_LATENT_DIM {
            return bad(
                "latent_dim",
                &self.latent_dim,
                format!("in 1..={MAX_LATENT_DIM}"),
            );
        }
        if self.restarts > MAX_RESTARTS {
            return bad(
                "restarts",
                &self.restarts,
                format!("at most {MAX_RESTARTS}"),
            );
        }
        for (name, v) in [
            ("amplitude", self.amplitude),
            ("lengthscale", self.lengthscale),
            ("noise", self.noise),
            ("initial_step", self.initial_step),
            ("min_step", self.min_step),
            ("gradient_tolerance", self.gradient_tolerance),
            ("cost_tolerance", self.cost_tolerance),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, &v, "finite and > 0".into());
            }
        }
        if self.min_step > self.initial_step {
            // Hooke-Jeeves would stop before its first move and write the PCA start.
            return bad(
                "min_step",
                &self.min_step,
                format!("at most initial_step ({})", self.initial_step),
            );
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", &0, ">= 1".into());
        }
        if self.max_evaluations == 0 {
            return bad("max_evaluations", &0, ">= 1".into());
        }
        if !(self.min_noise.is_finite() && self.min_noise >= 0.0) {
            return bad("min_noise", &self.min_noise, "finite and >= 0".into());
        }
        if self.learn_hyperparameters && self.noise <= self.min_noise {
            return bad(
                "noise",
                &self.noise,
                format!(
                    "above min_noise ({}) when hyperparameters are learnt",
                    self.min_noise
                ),
            );
        }
        let transform: Transform = self.transform.parse()?;
        Ok(FitConfig {
            params: self,
            transform,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Optimiser names round-trip through Display and FromStr (the model file and the CLI
    /// write and read them).
    #[test]
    fn optimizer_names_round_trip() {
        for (kind, name) in [
            (OptimizerKind::HookeJeeves, "hooke-jeeves"),
            (OptimizerKind::Lbfgs, "lbfgs"),
        ] {
            assert_eq!(kind.to_string(), name);
            assert_eq!(name.parse::<OptimizerKind>().unwrap(), kind);
        }
        assert!("bfgs".parse::<OptimizerKind>().is_err());
    }

    /// The bounds of `check` are inclusive where documented: q in 1..=MAX_LATENT_DIM, and a
    /// min_step equal to initial_step.
    #[test]
    fn check_accepts_its_bounds_and_refuses_past_them() {
        let with = |latent_dim, min_step| FitParams {
            latent_dim,
            min_step,
            initial_step: 0.5,
            ..FitParams::default()
        };
        assert!(with(1, 1e-3).check().is_ok());
        assert!(with(MAX_LATENT_DIM, 0.5).check().is_ok());
        for bad in [
            with(0, 1e-3),
            with(MAX_LATENT_DIM + 1, 1e-3),
            with(2, 0.5000001),
        ] {
            assert!(bad.clone().check().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn paper_config_parses() {
        let p: FitParams = toml::from_str(
            r#"
            latent_dim = 2
            optimizer = "hooke-jeeves"
            transform = "raw"
            lengthscale = 1.0
            noise = 1e-4
            "#,
        )
        .unwrap();
        let c = p.check().unwrap();
        assert_eq!(c.transform, Transform::Raw);
        assert_eq!(c.params.optimizer, OptimizerKind::HookeJeeves);
    }

    #[test]
    fn shipped_configs_parse_and_default_matches_code() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/fit");
        let paper = FitParams::from_toml_file(&dir.join("paper.toml"))
            .unwrap()
            .check()
            .unwrap();
        assert_eq!(paper.params.optimizer, OptimizerKind::HookeJeeves);
        assert_eq!(paper.transform, Transform::Raw);
        assert_eq!((paper.params.lengthscale, paper.params.noise), (1.0, 1e-4));
        let default = FitParams::from_toml_file(&dir.join("default.toml")).unwrap();
        assert_eq!(default, FitParams::default());
    }

    #[test]
    fn unknown_keys_and_bad_values_are_errors() {
        assert!(toml::from_str::<FitParams>("latent_dimension = 2").is_err());
        let p = FitParams {
            noise: 0.0,
            ..Default::default()
        };
        assert!(p.check().is_err());
        let p = FitParams {
            latent_dim: 0,
            ..Default::default()
        };
        assert!(p.check().is_err());
        let p = FitParams {
            transform: "exp".into(),
            ..Default::default()
        };
        assert!(p.check().is_err());
        let p = FitParams {
            restarts: MAX_RESTARTS + 1,
            ..Default::default()
        };
        let err = p.check().unwrap_err().to_string();
        assert!(
            err.contains("restarts = 1001: must be at most 1000"),
            "{err}"
        );
        let p = FitParams {
            restarts: MAX_RESTARTS,
            ..Default::default()
        };
        assert!(p.check().is_ok());
        let p = FitParams {
            min_step: 10.0,
            ..Default::default()
        };
        let err = p.check().unwrap_err().to_string();
        assert!(
            err.contains("min_step = 10: must be at most initial_step (0.1)"),
            "{err}"
        );
        for (min_noise, learn) in [(-1.0, false), (f64::NAN, false), (1e-4, true)] {
            let p = FitParams {
                min_noise,
                learn_hyperparameters: learn,
                ..Default::default()
            };
            let err = p.check().unwrap_err().to_string();
            assert!(err.contains("min_noise"), "{err}");
        }
    }
}
