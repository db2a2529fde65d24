//! A fit's options by name, for callers that name options rather than fields (the Python
//! package): every option is a flag of the `fit` subcommand with underscores for its
//! dashes, set from the text that flag takes ([`FitRequest::set`]) by the parsers the
//! command line's flags use ([`finite`], [`numbers`], [`coarse_to_fine`], [`window`],
//! [`early_stop`]). The defaults are [`FitRequest::new`]'s (the command line's), and the
//! refusals of settings that cannot act together are [`FitSettings`]'s, made when the fit
//! starts: a caller by name gets the command line's values, defaults and messages.
//!
//! [`FitSettings`]: crate::fit::settings::FitSettings

use std::path::PathBuf;

use crate::fit::coarse::CoarseToFine;
use crate::fit::defaults::{DEFAULT_COARSE_ENDS, DEFAULT_EARLY_STOP};
use crate::fit::settings::FitSettings;
use crate::fit::train::EarlyStop;
use crate::io::dataset::MAX_DOWNSCALE;
use crate::model::{Blend, Error, Result};
use crate::tasks::fit::FitRequest;

/// Every option of a fit, in the order of the `fit` subcommand's help.
pub const FIT_OPTIONS: &[&str] = &[
    "strict",
    "init",
    "blend",
    "log",
    "view",
    "downscale",
    "allow_outside_images",
    "frames",
    "fps",
    "dilation",
    "cutoff",
    "exp",
    "threads",
    "steps",
    "batch",
    "start_kernels",
    "max_kernels",
    "eval_every",
    "seed",
    "background",
    "lr_mean",
    "lr_time",
    "lr_amplitude",
    "lr_velocity",
    "lr_scale",
    "lr_final",
    "freeze_mean",
    "freeze_time",
    "freeze_amplitude",
    "densify_every",
    "densify_from",
    "densify_until",
    "densify_threshold",
    "max_growth",
    "prune_below",
    "mode",
    "fit_velocity",
    "fit_scale",
    "adaptive",
    "min_improvement",
    "merge_tolerance",
    "min_scale",
    "box",
    "time_range",
    "init_scale",
    "init_amplitude",
    "lr_background",
    "freeze_background",
    "sh",
    "sh_raise_every",
    "lr_opacity",
    "lr_rotation",
    "lr_acceleration",
    "lr_angular_velocity",
    "lr_sh",
    "opacity_reset_every",
    "percent_dense",
    "time_split_fraction",
    "coarse_to_fine",
    "early_stop",
    "window",
    "loss",
    "dssim_weight",
    "motion",
    "motion_after_splits",
    "prune_fraction",
    "prune_rounds",
    "opacity_regulariser",
    "scale_regulariser",
];

/// The port `view` serves on when switched on without one.
pub const DEFAULT_VIEW_PORT: u16 = 8080;

/// An option's value as a caller gives it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OptionValue<'a> {
    /// A switch's state (a flag without a value: given, or not); `view` on its default port.
    Switch(bool),
    /// The text the option's flag takes (`0.5`, `off`, `0,0,0`).
    Text(&'a str),
    /// The numbers of a list-valued option (`background`, `box`, `time_range`,
    /// `init_scale`), each as text.
    List(&'a [String]),
}

impl FitRequest {
    /// A fit of the dataset in `views` written to `out`, every other option at its default.
    #[must_use]
    pub fn new(views: PathBuf, out: PathBuf) -> FitRequest {
        FitRequest {
            views,
            downscale: 1,
            strict: false,
            allow_outside_images: false,
            frames: None,
            fps: None,
            init: "auto".into(),
            settings: FitSettings::default(),
            blend: None,
            out,
            log: None,
            threads: None,
            view: None,
        }
    }

    /// Sets the option `name` (one of [`FIT_OPTIONS`]) to `value`: a switch takes
    /// [`OptionValue::Switch`], a list-valued option [`OptionValue::List`] or its text, any
    /// other option its text. Refused naming the option: an unknown name, a value of the
    /// wrong kind, a text its flag refuses.
    pub fn set(&mut self, name: &str, value: OptionValue<'_>) -> Result<()> {
        let Some(&name) = FIT_OPTIONS.iter().find(|n| **n == name) else {
            return Err(Error::usage(format!(
                "fit: no option `{}` (the options are the `fit` subcommand's flags: {})",
                crate::model::error::cut(name, crate::model::error::MAX_QUOTE),
                FIT_OPTIONS.join(", ")
            )));
        };
        let v = Value { name, value };
        match name {
            "strict" => self.strict = v.switch()?,
            "init" => self.init = v.text()?.to_owned(),
            "blend" => self.blend = blend_choice(v.text()?)?,
            "log" => self.log = Some(PathBuf::from(v.text()?)),
            "view" => self.view = v.port()?,
            "downscale" => {
                let downscale = v.parse()?;
                check_downscale(downscale)?;
                self.downscale = downscale;
            }
            "allow_outside_images" => self.allow_outside_images = v.switch()?,
            "frames" => self.frames = Some(v.parse()?),
            "fps" => self.fps = Some(v.parse()?),
            "threads" => self.threads = Some(v.parse()?),
            _ => set_setting(&mut self.settings, &v)?,
        }
        Ok(())
    }
}

/// Sets the [`FitSettings`] option `v.name` (every option but the request's own).
fn set_setting(s: &mut FitSettings, v: &Value<'_>) -> Result<()> {
    let r = &mut s.rates;
    match v.name {
        "dilation" => s.render.dilation = v.number()?,
        "cutoff" => s.render.cutoff = v.number()?,
        "exp" => s.render.exp = v.parse()?,
        "steps" => s.steps = Some(v.parse()?),
        "batch" => s.batch = Some(v.parse()?),
        "start_kernels" => s.start_kernels = Some(v.parse()?),
        "max_kernels" => s.max_kernels = Some(v.parse()?),
        "eval_every" => s.eval_every = Some(v.parse()?),
        "seed" => s.seed = Some(v.parse()?),
        "background" => s.background = Some(v.numbers()?),
        "lr_mean" => r.mean = Some(v.number()?),
        "lr_time" => r.time = Some(v.number()?),
        "lr_amplitude" => r.amplitude = Some(v.number()?),
        "lr_velocity" => r.velocity = Some(v.number()?),
        "lr_scale" => r.scale = Some(v.number()?),
        "lr_final" => s.lr_final = Some(v.number()?),
        "freeze_mean" => s.freeze_mean = v.switch()?,
        "freeze_time" => s.freeze_time = v.switch()?,
        "freeze_amplitude" => s.freeze_amplitude = v.switch()?,
        "densify_every" => s.densify_every = Some(v.parse()?),
        "densify_from" => s.densify_from = Some(v.number()?),
        "densify_until" => s.densify_until = Some(v.number()?),
        "densify_threshold" => s.densify_threshold = Some(v.number()?),
        "max_growth" => s.max_growth = Some(v.number()?),
        "prune_below" => s.prune_below = Some(v.number()?),
        "mode" => s.mode = Some(v.parse()?),
        "fit_velocity" => s.fit_velocity = v.switch()?,
        "fit_scale" => s.fit_scale = v.switch()?,
        "adaptive" => s.adaptive = v.switch()?,
        "min_improvement" => s.min_improvement = Some(v.number()?),
        "merge_tolerance" => s.merge_tolerance = Some(v.number()?),
        "min_scale" => s.min_scale = Some(v.number()?),
        "box" => s.bounds = Some(v.numbers()?),
        "time_range" => s.time_range = Some(v.numbers()?),
        "init_scale" => s.init_scale = Some(v.numbers()?),
        "init_amplitude" => s.init_amplitude = Some(v.number()?),
        "lr_background" => r.background = Some(v.number()?),
        "freeze_background" => s.freeze_background = v.switch()?,
        _ => set_alpha_setting(s, v)?,
    }
    Ok(())
}

/// Sets the alpha fit's own [`FitSettings`] option `v.name`.
fn set_alpha_setting(s: &mut FitSettings, v: &Value<'_>) -> Result<()> {
    let r = &mut s.rates;
    match v.name {
        "sh" => s.sh = Some(v.parse()?),
        "sh_raise_every" => s.sh_raise_every = Some(v.parse()?),
        "lr_opacity" => r.opacity = Some(v.number()?),
        "lr_rotation" => r.rotation = Some(v.number()?),
        "lr_acceleration" => r.acceleration = Some(v.number()?),
        "lr_angular_velocity" => r.angular_velocity = Some(v.number()?),
        "lr_sh" => r.sh = Some(v.number()?),
        "opacity_reset_every" => s.opacity_reset_every = Some(v.parse()?),
        "percent_dense" => s.percent_dense = Some(v.number()?),
        "time_split_fraction" => s.time_split_fraction = Some(v.number()?),
        "coarse_to_fine" => s.coarse_to_fine = Some(v.with(coarse_to_fine)?),
        "early_stop" => s.early_stop = Some(v.with(early_stop)?),
        "window" => s.window = Some(v.with(window)?),
        "loss" => s.loss = Some(v.parse()?),
        "dssim_weight" => s.dssim_weight = Some(v.number()?),
        "motion" => s.motion = Some(v.parse()?),
        "motion_after_splits" => s.motion_after_splits = Some(v.parse()?),
        "prune_fraction" => s.prune_fraction = Some(v.number()?),
        "prune_rounds" => s.prune_rounds = Some(v.parse()?),
        "opacity_regulariser" => s.opacity_regulariser = Some(v.number()?),
        "scale_regulariser" => s.scale_regulariser = Some(v.number()?),
        other => unreachable!("`{other}` of FIT_OPTIONS has no arm"),
    }
    Ok(())
}

/// An option's value with its name, read as the kind the option takes.
struct Value<'a> {
    name: &'static str,
    value: OptionValue<'a>,
}

impl Value<'_> {
    fn refuse(&self, why: impl std::fmt::Display) -> Error {
        Error::setting(&[self.name], format!("`{}` {why}", self.name))
    }

    fn switch(&self) -> Result<bool> {
        match self.value {
            OptionValue::Switch(on) => Ok(on),
            _ => Err(self.refuse("is a switch: give true or false")),
        }
    }

    fn text(&self) -> Result<&str> {
        match self.value {
            OptionValue::Text(text) => Ok(text),
            OptionValue::Switch(_) => Err(self.refuse("takes a value, not true or false")),
            OptionValue::List(_) => Err(self.refuse("takes one value, not a list")),
        }
    }

    /// The text read by `parse`, its complaint naming the option.
    fn with<T>(&self, parse: impl Fn(&str) -> std::result::Result<T, String>) -> Result<T> {
        parse(self.text()?).map_err(|e| self.refuse(e))
    }

    /// The text read by the type's own parser (its `FromStr`, as for the flag).
    fn parse<T: std::str::FromStr<Err: std::fmt::Display>>(&self) -> Result<T> {
        self.with(|text| {
            text.parse::<T>()
                .map_err(|e| format!("`{}`: {e}", crate::model::error::cut(text, 40)))
        })
    }

    fn number(&self) -> Result<f64> {
        self.with(finite)
    }

    fn numbers<const N: usize>(&self) -> Result<[f64; N]> {
        match self.value {
            OptionValue::List(items) => numbers(&items.join(",")).map_err(|e| self.refuse(e)),
            _ => self.with(numbers),
        }
    }

    /// `view`: a port, or switched on (the default port) or off.
    fn port(&self) -> Result<Option<u16>> {
        match self.value {
            OptionValue::Switch(on) => Ok(on.then_some(DEFAULT_VIEW_PORT)),
            _ => self.parse().map(Some),
        }
    }
}

/// The blend chosen by `text`: `additive`, `alpha`, or `auto` (`None`: the fit chooses).
pub fn blend_choice(text: &str) -> Result<Option<Blend>> {
    match text {
        "auto" => Ok(None),
        _ => text.parse().map(Some).map_err(|_: String| {
            Error::setting(
                &["blend"],
                format!(
                    "`blend`: unknown blend {:?} (expected additive, alpha or auto)",
                    crate::model::error::cut(text, crate::model::error::MAX_QUOTE)
                ),
            )
        }),
    }
}

/// An error naming `downscale` when it is not a factor images are read at.
pub fn check_downscale(downscale: u32) -> Result<()> {
    if (1..=MAX_DOWNSCALE).contains(&downscale) {
        return Ok(());
    }
    Err(Error::setting(
        &["downscale"],
        format!("`downscale` {downscale} must be between 1 and {MAX_DOWNSCALE}"),
    ))
}

/// A finite number (NaN and ±∞ are refused before any work).
pub fn finite(text: &str) -> std::result::Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(format!("{v} is not finite")),
        Err(e) => Err(format!("`{text}`: {e}")),
    }
}

/// `N` comma-separated finite numbers.
pub fn numbers<const N: usize>(text: &str) -> std::result::Result<[f64; N], String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().map_err(|e| format!("`{v}`: {e}")))
        .collect::<std::result::Result<_, _>>()?;
    let array: [f64; N] = values
        .try_into()
        .map_err(|v: Vec<f64>| format!("expected {N} comma-separated numbers, got {}", v.len()))?;
    match array.iter().find(|v| !v.is_finite()) {
        Some(v) => Err(format!("{v} is not finite")),
        None => Ok(array),
    }
}

/// `off`, or the shorter side (pixels, ≥ 1) a coarse stage keeps: the default stages'
/// ends ([`DEFAULT_COARSE_ENDS`]) with that side.
pub fn coarse_to_fine(text: &str) -> std::result::Result<CoarseToFine, String> {
    let text = text.trim();
    if text == "off" {
        return Ok(CoarseToFine::Off);
    }
    match text.parse::<u32>() {
        Ok(min_side) if min_side >= 1 => Ok(CoarseToFine::Auto {
            min_side,
            ends: DEFAULT_COARSE_ENDS,
        }),
        _ => Err(format!(
            "`{text}`: give `off` or the shorter side in pixels (an integer ≥ 1) a coarse stage keeps"
        )),
    }
}

/// `off` (`None`: whole views), or a window's largest side in pixels (an integer ≥ 16, a
/// tile).
pub fn window(text: &str) -> std::result::Result<Option<u32>, String> {
    let text = text.trim();
    if text == "off" {
        return Ok(None);
    }
    match text.parse::<u32>() {
        Ok(side) if side >= 16 => Ok(Some(side)),
        _ => Err(format!(
            "`{text}`: give `off` or a window side in pixels (an integer ≥ 16)"
        )),
    }
}

/// `off` (`None`), or the fraction of the steps (in (0, 1]) without a gain that ends a fit,
/// with the default gain ([`DEFAULT_EARLY_STOP`]).
pub fn early_stop(text: &str) -> std::result::Result<Option<EarlyStop>, String> {
    let text = text.trim();
    if text == "off" {
        return Ok(None);
    }
    match text.parse::<f64>() {
        Ok(flat_fraction) if flat_fraction > 0.0 && flat_fraction <= 1.0 => Ok(Some(EarlyStop {
            flat_fraction,
            ..DEFAULT_EARLY_STOP
        })),
        _ => Err(format!(
            "`{text}`: give `off` or a fraction of the steps in (0, 1]"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::settings::{ADDITIVE_ONLY, ALPHA_ONLY, BOTH_BLENDS};

    fn request() -> FitRequest {
        FitRequest::new("views".into(), "out.json".into())
    }

    #[test]
    fn every_setting_is_an_option_with_its_arm() {
        for name in BOTH_BLENDS.iter().chain(&ADDITIVE_ONLY).chain(&ALPHA_ONLY) {
            // The rendering options are three flags of their own.
            if *name != "render" {
                assert!(FIT_OPTIONS.contains(name), "{name}");
            }
        }
        for name in FIT_OPTIONS {
            let mut r = request();
            // Any value reaches the option's own arm: refused as a kind or a text, never
            // as an unknown option (nor a panic).
            for value in [OptionValue::Switch(true), OptionValue::Text("1")] {
                if let Err(e) = r.set(name, value) {
                    assert!(!e.to_string().contains("no option"), "{name}: {e}");
                }
            }
        }
    }

    #[test]
    fn values_of_the_wrong_kind_or_text_are_refused_naming_the_option() {
        let mut r = request();
        let message = |r: &mut FitRequest, name, value| r.set(name, value).unwrap_err().to_string();
        assert_eq!(
            message(&mut r, "steps", OptionValue::Switch(true)),
            "`steps` takes a value, not true or false"
        );
        assert_eq!(
            message(&mut r, "adaptive", OptionValue::Text("yes")),
            "`adaptive` is a switch: give true or false"
        );
        assert!(
            message(&mut r, "window", OptionValue::Text("8"))
                .starts_with("`window` `8`: give `off`")
        );
        assert_eq!(
            message(&mut r, "lr_mean", OptionValue::Text("NaN")),
            "`lr_mean` NaN is not finite"
        );
        let two = ["1".to_string(), "2".to_string()];
        assert_eq!(
            message(&mut r, "background", OptionValue::List(&two)),
            "`background` expected 3 comma-separated numbers, got 2"
        );
        assert_eq!(
            message(&mut r, "steps", OptionValue::List(&two)),
            "`steps` takes one value, not a list"
        );
        assert!(
            message(&mut r, "lr_means", OptionValue::Text("1"))
                .starts_with("fit: no option `lr_means`")
        );
        assert_eq!(
            message(&mut r, "downscale", OptionValue::Text("0")),
            format!("`downscale` 0 must be between 1 and {MAX_DOWNSCALE}")
        );
        assert_eq!(r, request(), "a refused value changes nothing");
    }

    #[test]
    fn options_set_the_fields_their_flags_set() {
        let mut r = request();
        r.set("window", OptionValue::Text("off")).unwrap();
        r.set("early_stop", OptionValue::Text("0.2")).unwrap();
        r.set("loss", OptionValue::Text("mse")).unwrap();
        r.set("view", OptionValue::Switch(true)).unwrap();
        r.set("blend", OptionValue::Text("auto")).unwrap();
        r.set("background", OptionValue::Text("0.5, 0.5,0.5"))
            .unwrap();
        let s = &r.settings;
        assert_eq!(s.window, Some(None));
        assert_eq!(s.early_stop.flatten().map(|e| e.flat_fraction), Some(0.2));
        assert_eq!(s.loss, Some(crate::fit::train::LossName::Mse));
        assert_eq!(s.background, Some([0.5; 3]));
        assert_eq!((r.view, r.blend), (Some(DEFAULT_VIEW_PORT), None));
    }
}
