//! [`PairRow`]s ↔ an Arrow [`RecordBatch`] of the pairs v3 schema, an exact round trip. Version-1 and
//! version-2 batches are read too (through [`super::pairs_versions::to_current`]).
//!
//! Unsigned row fields are stored in signed columns bit for bit (`seed as i64`); reading casts back.
//! Over 400 lines because the writer and the reader of the schema stay side by side: a column added to
//! one is seen next to the other.

use super::pairs_versions::to_current;
use super::row::{PairRow, StageTiming, Status};
use super::schema::{list_item, pairs_schema, timing_fields, type_notation};
use crate::error::{Error, Result};
use crate::geometry::Point;
use arrow::array::{
    Array, ArrayRef, BinaryArray, FixedSizeListArray, Float32Array, Float64Array, Int32Array, Int64Array, Int8Array,
    ListArray, RecordBatch, StringArray, StructArray,
};
use arrow::buffer::OffsetBuffer;
use std::sync::Arc;

/// Builds one batch (pairs v3 schema) holding `rows` in order.
pub fn pairs_to_batch(rows: &[PairRow]) -> Result<RecordBatch> {
    let schema = pairs_schema();
    let ty = |name: &str| schema.field_with_name(name).expect("pairs schema column").data_type().clone();
    let utf8 = |f: fn(&PairRow) -> &str| -> ArrayRef { Arc::new(StringArray::from_iter_values(rows.iter().map(f))) };
    let binary = |f: fn(&PairRow) -> &[u8]| -> ArrayRef { Arc::new(BinaryArray::from_iter_values(rows.iter().map(f))) };
    // Bit for bit: a u32 / u64 field in an int32 / int64 column.
    let u32s = |f: fn(&PairRow) -> u32| -> ArrayRef { Arc::new(Int32Array::from_iter_values(rows.iter().map(|r| f(r) as i32))) };
    let u64s = |f: fn(&PairRow) -> u64| -> ArrayRef { Arc::new(Int64Array::from_iter_values(rows.iter().map(|r| f(r) as i64))) };
    let f64s = |f: fn(&PairRow) -> f64| -> ArrayRef { Arc::new(Float64Array::from_iter_values(rows.iter().map(f))) };
    let vectors = |name: &str, f: fn(&PairRow) -> &[f64]| -> Result<ArrayRef> {
        let t = ty(name);
        let n = match &t {
            arrow::datatypes::DataType::FixedSizeList(_, n) => *n,
            _ => unreachable!("{name} is a fixed-size list"),
        };
        let values = Float64Array::from_iter_values(rows.iter().flat_map(|r| f(r).iter().copied()));
        let array = FixedSizeListArray::try_new(list_item(&t), n, Arc::new(values), None).map_err(arrow_err(name))?;
        Ok(Arc::new(array))
    };
    let clouds = |name: &str, f: fn(&PairRow) -> &Vec<Point>| -> Result<ArrayRef> {
        let t = ty(name);
        let point_field = list_item(&t);
        let coords =
            Float32Array::from_iter_values(rows.iter().flat_map(|r| f(r).iter().flat_map(|p| [p.x, p.y, p.z])));
        let points = FixedSizeListArray::try_new(list_item(point_field.data_type()), 3, Arc::new(coords), None)
            .map_err(arrow_err(name))?;
        let offsets = offsets(name, rows.iter().map(|r| f(r).len()))?;
        Ok(Arc::new(ListArray::try_new(point_field, offsets, Arc::new(points), None).map_err(arrow_err(name))?))
    };
    let provenance = |name: &str, values: ArrayRef, lengths: &dyn Fn(&PairRow) -> usize| -> Result<ArrayRef> {
        let offsets = offsets(name, rows.iter().map(lengths))?;
        Ok(Arc::new(ListArray::try_new(list_item(&ty(name)), offsets, values, None).map_err(arrow_err(name))?))
    };
    let known_share = provenance(
        "target_known_share",
        Arc::new(Float32Array::from_iter_values(rows.iter().flat_map(|r| r.target_known_share.iter().copied()))),
        &|r| r.target_known_share.len(),
    )?;
    let scene_share = provenance(
        "target_scene_share",
        Arc::new(Float32Array::from_iter_values(rows.iter().flat_map(|r| r.target_scene_share.iter().copied()))),
        &|r| r.target_scene_share.len(),
    )?;
    let view = provenance(
        "target_view",
        Arc::new(Int8Array::from_iter_values(rows.iter().flat_map(|r| r.target_view.iter().map(|&v| v as i8)))),
        &|r| r.target_view.len(),
    )?;
    let timings = {
        let t = ty("timings");
        let all = || rows.iter().flat_map(|r| r.timings.iter());
        let stage: ArrayRef = Arc::new(StringArray::from(all().map(|s| s.stage.as_str()).collect::<Vec<_>>()));
        let ms: ArrayRef = Arc::new(Float64Array::from_iter_values(all().map(|s| s.ms)));
        let entries = StructArray::try_new(timing_fields(), vec![stage, ms], None).map_err(arrow_err("timings"))?;
        let offsets = offsets("timings", rows.iter().map(|r| r.timings.len()))?;
        Arc::new(ListArray::try_new(list_item(&t), offsets, Arc::new(entries), None).map_err(arrow_err("timings"))?)
    };
    let columns: Vec<ArrayRef> = vec![
        u64s(|r| r.unit_index),
        utf8(|r| &r.pair_key),
        utf8(|r| &r.scene),
        utf8(|r| &r.frame_key),
        u32s(|r| r.sample_index),
        utf8(|r| &r.source_path),
        utf8(|r| &r.source_hash),
        utf8(|r| r.status.as_str()),
        utf8(|r| &r.message),
        u64s(|r| r.seed),
        u32s(|r| r.width),
        u32s(|r| r.height),
        vectors("source_intrinsics", |r| &r.source_intrinsics)?,
        vectors("target_intrinsics", |r| &r.target_intrinsics)?,
        vectors("t_target_from_source", |r| &r.t_target_from_source)?,
        u32s(|r| r.pose_draws),
        u32s(|r| r.scene_frames),
        clouds("source_points", |r| &r.source_points)?,
        clouds("target_points", |r| &r.target_points)?,
        known_share,
        scene_share,
        view,
        f64s(|r| r.overlap_source),
        f64s(|r| r.overlap_target),
        binary(|r| &r.source_depth_png),
        binary(|r| &r.condition_depth_png),
        binary(|r| &r.target_depth_png),
        binary(|r| &r.known_mask_png),
        utf8(|r| &r.config_hash),
        utf8(|r| &r.code_version),
        utf8(|r| &r.stages),
        timings,
    ];
    RecordBatch::try_new(schema, columns).map_err(|e| Error::Parquet(format!("building a pairs batch: {e}")))
}

/// Reads every row of a pairs batch (v3, or an earlier version: [`to_current`]). Errors name the
/// column when the batch does not match its version's schema.
pub fn batch_to_pairs(batch: &RecordBatch) -> Result<Vec<PairRow>> {
    let batch = &to_current(batch)?;
    let c = Columns(batch);
    let unit_index = c.get::<Int64Array>("unit_index")?;
    let pair_key = c.get::<StringArray>("pair_key")?;
    let scene = c.get::<StringArray>("scene")?;
    let frame_key = c.get::<StringArray>("frame_key")?;
    let sample_index = c.get::<Int32Array>("sample_index")?;
    let source_path = c.get::<StringArray>("source_path")?;
    let source_hash = c.get::<StringArray>("source_hash")?;
    let status = c.get::<StringArray>("status")?;
    let message = c.get::<StringArray>("message")?;
    let seed = c.get::<Int64Array>("seed")?;
    let width = c.get::<Int32Array>("width")?;
    let height = c.get::<Int32Array>("height")?;
    let source_intrinsics = c.vectors::<4>("source_intrinsics")?;
    let target_intrinsics = c.vectors::<4>("target_intrinsics")?;
    let t_target_from_source = c.vectors::<16>("t_target_from_source")?;
    let pose_draws = c.get::<Int32Array>("pose_draws")?;
    let scene_frames = c.get::<Int32Array>("scene_frames")?;
    let source_points = c.clouds("source_points")?;
    let target_points = c.clouds("target_points")?;
    let known_share = c.lists::<Float32Array>("target_known_share")?;
    let scene_share = c.lists::<Float32Array>("target_scene_share")?;
    let view = c.lists::<Int8Array>("target_view")?;
    let overlap_source = c.get::<Float64Array>("overlap_source")?;
    let overlap_target = c.get::<Float64Array>("overlap_target")?;
    let source_depth_png = c.get::<BinaryArray>("source_depth_png")?;
    let condition_depth_png = c.get::<BinaryArray>("condition_depth_png")?;
    let target_depth_png = c.get::<BinaryArray>("target_depth_png")?;
    let known_mask_png = c.get::<BinaryArray>("known_mask_png")?;
    let config_hash = c.get::<StringArray>("config_hash")?;
    let code_version = c.get::<StringArray>("code_version")?;
    let stages = c.get::<StringArray>("stages")?;
    let timings = c.timings()?;

    let mut source_points = source_points.into_iter();
    let mut target_points = target_points.into_iter();
    let mut timings = timings.into_iter();
    (0..batch.num_rows())
        .map(|i| {
            let status = Status::parse(status.value(i)).ok_or_else(|| {
                Error::Parquet(format!("column `status`: row {i} has unknown status {:?}", status.value(i)))
            })?;
            Ok(PairRow {
                unit_index: unit_index.value(i) as u64,
                pair_key: pair_key.value(i).to_string(),
                scene: scene.value(i).to_string(),
                frame_key: frame_key.value(i).to_string(),
                sample_index: sample_index.value(i) as u32,
                source_path: source_path.value(i).to_string(),
                source_hash: source_hash.value(i).to_string(),
                status,
                message: message.value(i).to_string(),
                seed: seed.value(i) as u64,
                width: width.value(i) as u32,
                height: height.value(i) as u32,
                source_intrinsics: source_intrinsics[i],
                target_intrinsics: target_intrinsics[i],
                t_target_from_source: t_target_from_source[i],
                pose_draws: pose_draws.value(i) as u32,
                scene_frames: scene_frames.value(i) as u32,
                source_points: source_points.next().expect("one cloud per row"),
                target_points: target_points.next().expect("one cloud per row"),
                target_known_share: known_share.0.values()[known_share.1[i]..known_share.1[i + 1]].to_vec(),
                target_scene_share: scene_share.0.values()[scene_share.1[i]..scene_share.1[i + 1]].to_vec(),
                target_view: view.0.values()[view.1[i]..view.1[i + 1]].iter().map(|&v| v as u8).collect(),
                overlap_source: overlap_source.value(i),
                overlap_target: overlap_target.value(i),
                source_depth_png: source_depth_png.value(i).to_vec(),
                condition_depth_png: condition_depth_png.value(i).to_vec(),
                target_depth_png: target_depth_png.value(i).to_vec(),
                known_mask_png: known_mask_png.value(i).to_vec(),
                config_hash: config_hash.value(i).to_string(),
                code_version: code_version.value(i).to_string(),
                stages: stages.value(i).to_string(),
                timings: timings.next().expect("one timing list per row"),
            })
        })
        .collect()
}

/// Typed access to the columns of a batch, with errors naming the column.
struct Columns<'a>(&'a RecordBatch);

impl Columns<'_> {
    fn column(&self, name: &str) -> Result<&ArrayRef> {
        let array = self.0.column_by_name(name).ok_or_else(|| Error::Parquet(format!("column `{name}` is missing")))?;
        no_nulls(name, array.as_ref())?;
        Ok(array)
    }

    fn get<T: Array + 'static>(&self, name: &str) -> Result<&T> {
        let array = self.column(name)?;
        downcast(name, array.as_ref())
    }

    fn vectors<const N: usize>(&self, name: &str) -> Result<Vec<[f64; N]>> {
        let list = self.get::<FixedSizeListArray>(name)?;
        if list.value_length() as usize != N {
            return Err(Error::Parquet(format!(
                "column `{name}`: {} values per row, expected {N}",
                list.value_length()
            )));
        }
        let values = list.values();
        no_nulls(name, values.as_ref())?;
        let values = downcast::<Float64Array>(name, values.as_ref())?.values();
        Ok(values.chunks_exact(N).map(|c| c.try_into().expect("chunk of N")).collect())
    }

    /// A `list<primitive>` column: its values and the offsets into them (rows + 1 of them).
    fn lists<T: Array + 'static>(&self, name: &str) -> Result<(&T, Vec<usize>)> {
        let list = self.get::<ListArray>(name)?;
        no_nulls(name, list.values().as_ref())?;
        let values = downcast::<T>(name, list.values().as_ref())?;
        Ok((values, list.offsets().iter().map(|&o| o as usize).collect()))
    }

    fn clouds(&self, name: &str) -> Result<Vec<Vec<Point>>> {
        let list = self.get::<ListArray>(name)?;
        let points = list.values();
        no_nulls(name, points.as_ref())?;
        let points = downcast::<FixedSizeListArray>(name, points.as_ref())?;
        let coords = points.values();
        no_nulls(name, coords.as_ref())?;
        let coords = downcast::<Float32Array>(name, coords.as_ref())?.values();
        if points.value_length() != 3 || coords.len() != 3 * points.len() {
            return Err(Error::Parquet(format!("column `{name}`: points are not 3 float32 each")));
        }
        Ok(list
            .offsets()
            .windows(2)
            .map(|w| {
                let (a, b) = (w[0] as usize, w[1] as usize);
                coords[3 * a..3 * b].chunks_exact(3).map(|p| Point::new(p[0], p[1], p[2])).collect()
            })
            .collect())
    }

    fn timings(&self) -> Result<Vec<Vec<StageTiming>>> {
        let name = "timings";
        let list = self.get::<ListArray>(name)?;
        let entries = list.values();
        no_nulls(name, entries.as_ref())?;
        let entries = downcast::<StructArray>(name, entries.as_ref())?;
        let field = |f: &str| -> Result<&ArrayRef> {
            let a =
                entries.column_by_name(f).ok_or_else(|| Error::Parquet(format!("column `{name}`: no field `{f}`")))?;
            no_nulls(name, a.as_ref())?;
            Ok(a)
        };
        let stage = downcast::<StringArray>(name, field("stage")?.as_ref())?;
        let ms = downcast::<Float64Array>(name, field("ms")?.as_ref())?;
        Ok(list
            .offsets()
            .windows(2)
            .map(|w| {
                (w[0] as usize..w[1] as usize)
                    .map(|j| StageTiming { stage: stage.value(j).to_string(), ms: ms.value(j) })
                    .collect()
            })
            .collect())
    }
}

fn downcast<'a, T: Array + 'static>(name: &str, array: &'a dyn Array) -> Result<&'a T> {
    array.as_any().downcast_ref::<T>().ok_or_else(|| {
        Error::Parquet(format!("column `{name}` has an unexpected type {}", type_notation(array.data_type())))
    })
}

fn no_nulls(name: &str, array: &dyn Array) -> Result<()> {
    match array.logical_null_count() {
        0 => Ok(()),
        n => Err(Error::Parquet(format!("column `{name}` holds {n} nulls; the pairs schema has none"))),
    }
}

/// List offsets from per-row lengths; errors when the batch holds more than `i32::MAX` values in a column.
fn offsets(name: &str, lengths: impl Iterator<Item = usize>) -> Result<OffsetBuffer<i32>> {
    let lengths: Vec<usize> = lengths.collect();
    let total: usize = lengths.iter().sum();
    if total > i32::MAX as usize {
        return Err(Error::Parquet(format!(
            "column `{name}`: {total} values in one batch exceed the list limit; write smaller shards"
        )));
    }
    Ok(OffsetBuffer::from_lengths(lengths))
}

fn arrow_err(name: &str) -> impl Fn(arrow::error::ArrowError) -> Error + '_ {
    move |e| Error::Parquet(format!("column `{name}`: {e}"))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use arrow::datatypes::{DataType, Field, Schema};

    /// A varied row: `k` picks the status, clouds and PNG sizes (some empty).
    pub(crate) fn sample_row(unit: u64) -> PairRow {
        let k = unit as usize;
        let status = [Status::Ok, Status::LowOverlap, Status::TooFewPoints, Status::InputError][k % 4];
        let cloud = |n: usize, s: f32| (0..n).map(|i| Point::new(i as f32 * s, -(i as f32) * 0.5, 1.0 + s)).collect();
        let mut pose = [0.0; 16];
        for (i, v) in pose.iter_mut().enumerate() {
            *v = (i as f64 + unit as f64) * 0.125 - 1.0 / 3.0;
        }
        PairRow {
            unit_index: unit,
            pair_key: format!("scene-{}/frame-{unit:06}#{}", k % 3, k % 2),
            scene: format!("scene-{}", k % 3),
            frame_key: format!("scene-{}/frame-{unit:06}", k % 3),
            sample_index: (k % 2) as u32,
            source_path: format!("/data/scene/frame-{unit:06}.depth.png"),
            source_hash: blake3::hash(&unit.to_le_bytes()).to_hex().to_string(),
            status,
            message: if status == Status::Ok { String::new() } else { format!("rejected {unit} ✓") },
            seed: u64::MAX - unit,
            width: 160,
            height: 120,
            source_intrinsics: [100.5, 101.25, 79.5, 59.5],
            target_intrinsics: [100.5, 101.25, 80.0, 60.0 + unit as f64],
            t_target_from_source: pose,
            pose_draws: k as u32 + 1,
            scene_frames: (k % 3) as u32 * 17,
            source_points: if status == Status::InputError { vec![] } else { cloud(10 + 7 * k, 0.01) },
            target_points: if status == Status::InputError { vec![] } else { cloud(3 + 5 * k, -0.02) },
            target_known_share: if status == Status::InputError { vec![] } else { (0..3 + 5 * k).map(|i| (i % 4) as f32 / 3.0).collect() },
            target_scene_share: if status == Status::InputError { vec![] } else { (0..3 + 5 * k).map(|i| (3 - i % 4) as f32 / 6.0).collect() },
            target_view: if status == Status::InputError { vec![] } else { (0..3 + 5 * k).map(|i| (i % 3) as u8).collect() },
            overlap_source: 0.1 + 0.3 * (k % 3) as f64,
            overlap_target: 1.0 / (1.0 + k as f64),
            source_depth_png: vec![k as u8; k * 3],
            condition_depth_png: if k % 2 == 0 { vec![] } else { vec![1, 2, 3, 0, 255] },
            target_depth_png: vec![0; k],
            known_mask_png: vec![],
            config_hash: "c0ffee".into(),
            code_version: crate::shards::CODE_VERSION.into(),
            stages: r#"[{"stage":"reproject"}]"#.into(),
            timings: (0..k % 3).map(|j| StageTiming { stage: format!("stage{j}"), ms: 0.25 + j as f64 }).collect(),
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let rows: Vec<PairRow> = (0..9).map(sample_row).collect();
        let batch = pairs_to_batch(&rows).unwrap();
        assert_eq!(batch.num_rows(), 9);
        assert_eq!(batch.schema(), pairs_schema());
        let back = batch_to_pairs(&batch).unwrap();
        assert_eq!(back, rows);
        for (a, b) in rows.iter().zip(&back) {
            assert_eq!(a.content_digest(), b.content_digest());
        }
    }

    #[test]
    fn sliced_batch_reads_its_own_rows() {
        let rows: Vec<PairRow> = (0..6).map(sample_row).collect();
        let batch = pairs_to_batch(&rows).unwrap();
        assert_eq!(batch_to_pairs(&batch.slice(2, 3)).unwrap(), rows[2..5]);
    }

    #[test]
    fn empty_batch() {
        let batch = pairs_to_batch(&[]).unwrap();
        assert_eq!(batch.num_rows(), 0);
        assert!(batch_to_pairs(&batch).unwrap().is_empty());
    }

    #[test]
    fn wrong_batches_are_refused_naming_the_column() {
        let batch = pairs_to_batch(&[sample_row(1)]).unwrap();
        // A batch without the `seed` column.
        let keep: Vec<usize> = (0..batch.num_columns()).filter(|&i| i != 9).collect();
        let batch = &batch; // the same batch for the cases below
        let err = batch_to_pairs(&batch.project(&keep).unwrap()).unwrap_err().to_string();
        assert!(err.contains("seed"), "{err}");
        // An unknown status value.
        let mut columns = batch.columns().to_vec();
        columns[7] = Arc::new(StringArray::from(vec!["maybe"]));
        let bad = RecordBatch::try_new(batch.schema(), columns).unwrap();
        let err = batch_to_pairs(&bad).unwrap_err().to_string();
        assert!(err.contains("status") && err.contains("maybe"), "{err}");
        // A column of the wrong type.
        let mut fields: Vec<Field> = batch.schema().fields().iter().map(|f| f.as_ref().clone()).collect();
        fields[0] = Field::new("unit_index", DataType::UInt64, false);
        let mut columns = batch.columns().to_vec();
        columns[0] = Arc::new(arrow::array::UInt64Array::from(vec![1]));
        let bad = RecordBatch::try_new(Arc::new(Schema::new_with_metadata(fields, batch.schema().metadata().clone())), columns).unwrap();
        let err = batch_to_pairs(&bad).unwrap_err().to_string();
        assert!(err.contains("unit_index") && err.contains("uint64"), "{err}");
    }
}
