//! Raw brackets in the darkroom: their response is known (linear after the black level,
//! clipped at the white level), so no response is fitted or chosen; the merge is
//! [`crate::raw::develop`].

use super::{ChosenResponse, DarkroomError, Source, Stages};
use crate::align::{self, AlignMode, Alignment, MosaicFrame};
use crate::frame::{LoadedFrame, Samples};
use crate::merge::{BracketOrder, Merged};
use crate::radiance::RadianceMap;
use crate::raw::dng::{self, DngBracket};
use crate::raw::mosaic::MergedMosaic;
use crate::raw::{self, RawError, RawExposure, RawInfo};
use crate::response::InverseResponse;

/// What the report and the EXR header say a raw bracket's response is.
const LINEAR_RAW: &str = "linear (raw)";

/// A merged raw bracket.
pub(super) struct RawMerge {
    /// The response reported (linear).
    pub chosen: ChosenResponse,
    /// The radiance in linear Rec. 709.
    pub merged: Merged,
    /// How the mosaics were aligned.
    pub alignment: Alignment,
    /// The merged mosaic and what a DNG of it needs, when it was asked for.
    pub dng: Option<DngSource>,
}

/// What [`dng::encode`] needs of a merged raw bracket, owned.
pub(super) struct DngSource {
    mosaic: MergedMosaic,
    colour: RawInfo,
    shortest: RawInfo,
    ratio: f64,
}

impl DngSource {
    /// The DNG's bytes.
    pub fn encode(&self) -> Result<Vec<u8>, dng::DngError> {
        dng::encode(&DngBracket {
            mosaic: &self.mosaic,
            colour: &self.colour,
            shortest: &self.shortest,
            ratio: self.ratio,
        })
    }
}

/// Merges `frames` when they are raws (`None` when none is): the response reported and
/// the merged radiance in linear Rec. 709 times `scale` (stage `merge+demosaic`), after
/// the mosaics are aligned under `align` (stage `align`, see [`crate::align`]'s "Camera
/// raw"), and with `keep_mosaic` the merged mosaic for a DNG. A bracket that mixes raw
/// and other frames is refused.
pub(super) fn merge(
    frames: &[LoadedFrame],
    exposures: &[f64],
    scale: f64,
    align: AlignMode,
    keep_mosaic: bool,
    stages: &mut Stages,
) -> Result<Option<RawMerge>, DarkroomError> {
    let Some(first_raw) = frames.iter().find(|f| f.raw.is_some()) else {
        return Ok(None);
    };
    let inputs = raw_exposures(frames, exposures, first_raw)?;
    let (alignment, warped) = align_mosaics(&inputs, align, stages);
    let inputs: Vec<RawExposure<'_>> = inputs
        .iter()
        .zip(&warped)
        .map(|(input, codes)| RawExposure {
            codes: codes.as_deref().unwrap_or(input.codes),
            ..*input
        })
        .collect();
    let mut developed = raw::develop_keeping(&inputs, scale, keep_mosaic)?;
    stages.extend(developed.timings.iter().copied());
    let exposures: Vec<f64> = developed.order.iter().map(|&i| exposures[i]).collect();
    let info = inputs[0].info;
    let dng = developed.mosaic.take().map(|mosaic| {
        let (shortest, longest) = (
            developed.order[0],
            developed.order[developed.order.len() - 1],
        );
        DngSource {
            mosaic,
            colour: info.clone(),
            shortest: inputs[shortest].info.clone(),
            ratio: inputs[longest].exposure / inputs[shortest].exposure,
        }
    });
    let radiance = RadianceMap::new(developed.width, developed.height, 3, developed.rgb)
        .expect("three values per pixel of the mosaic");
    let chosen = linear_response(info, developed.demosaic);
    Ok(Some(RawMerge {
        chosen,
        merged: Merged {
            radiance,
            confidence: None,
            bracket: BracketOrder {
                order: developed.order,
                exposures,
                clipped_high: developed.clipped,
                clipped_low: 0,
            },
        },
        alignment,
        dng,
    }))
}

/// Each of `frames` as a raw exposure of its relative `exposures`; a frame that is not a
/// raw refuses the bracket, naming it beside `first_raw`.
fn raw_exposures<'f>(
    frames: &'f [LoadedFrame],
    exposures: &[f64],
    first_raw: &LoadedFrame,
) -> Result<Vec<RawExposure<'f>>, DarkroomError> {
    let mut inputs = Vec::with_capacity(frames.len());
    for (f, &exposure) in frames.iter().zip(exposures) {
        let (Some(info), Samples::Sixteen(codes)) = (f.raw.as_deref(), f.frame.samples()) else {
            return Err(RawError::Mismatch {
                first: first_raw.path.clone(),
                other: f.path.clone(),
                reason: "a bracket is either all raw or all JPEG/PNG/TIFF".to_string(),
            }
            .into());
        };
        inputs.push(RawExposure {
            path: &f.path,
            codes,
            width: f.frame.width(),
            height: f.frame.height(),
            info,
            exposure,
        });
    }
    Ok(inputs)
}

/// The response reported for a raw bracket of the camera of `info`: linear, with its
/// black and white levels, colour filter array, `demosaic` method and colour conversion.
fn linear_response(info: &RawInfo, demosaic: &str) -> ChosenResponse {
    ChosenResponse {
        response: InverseResponse::from_samples(vec![vec![0.0, 1.0]; 3])
            .expect("a straight line is a valid response"),
        source: Source::Raw,
        summary: LINEAR_RAW.to_string(),
        report: serde_json::json!({
            "source": Source::Raw,
            "model": LINEAR_RAW,
            "camera": info.camera(),
            "black": info.black,
            "white": info.white,
            "cfa": info.cfa.name(),
            "demosaic": demosaic,
            "colour": format!("camera → XYZ ({} matrix) → Rec. 709, as-shot neutral {:?}", info.matrix_illuminant, info.neutral),
        }),
        fit: None,
        notes: Vec::new(),
        contradicts_cache: false,
        pooling: None,
    }
}

/// The mosaics' alignment under `mode` (stage `align`, unless `off`) and each moved
/// mosaic resampled onto the reference grid (`None` for one merged as it is).
fn align_mosaics(
    inputs: &[RawExposure<'_>],
    mode: AlignMode,
    stages: &mut Stages,
) -> (Alignment, Vec<Option<Vec<u16>>>) {
    let t = std::time::Instant::now();
    let mosaics: Vec<MosaicFrame<'_>> = inputs
        .iter()
        .map(|i| MosaicFrame {
            codes: i.codes,
            width: i.width as usize,
            height: i.height as usize,
            info: i.info,
            exposure: i.exposure,
        })
        .collect();
    let alignment = align::align_mosaics(&mosaics, mode);
    let warped = align::warp_mosaics(&mosaics, &alignment);
    if mode != AlignMode::Off {
        stages.push(("align", t.elapsed()));
    }
    (alignment, warped)
}
