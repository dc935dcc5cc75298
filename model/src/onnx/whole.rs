//! The whole predictor as one ONNX graph: the camera's crop (uint8 RGB) in, depth in mm on the
//! crop out, as `infer`'s `Predictor` computes it, so that ONNX Runtime, TensorRT or OpenCV's DNN
//! module need nothing else from the bundle.
//!
//! The graph replays, in order: the drift balance against the reference frame (the trimmed
//! median of frame / reference ratios per channel, `sensor::gate::Balance`, binned by table into
//! histograms (`ScatterElements` adding) whose running counts (`CumSum`) give the medians), the contact gate (an `If`: an untouched frame gives zeros without running
//! the network), the resize to the network's input (the `image` crate's triangle taps summed in
//! its order, rounded to grey levels), the input encoding with the reference as a constant, the
//! network, the depth scale,
//! the tare (the network's depth on the reference, a constant), the extrapolation over the
//! untrained border (`FillPlan`'s rings as gathers), the upsampling to the crop (two matrix
//! products), the clamp and the useful-disk mask; with the pressure output, the pressure (kPa)
//! kept where the depth shows contact, and its resultant force; with the force head, the head's
//! force (tared, zero without contact) and the pressure scaled to it.

use burn::tensor::{Tensor, TensorData};
use image::RgbImage;

use super::proto::*;
use super::{Graph, OnnxError, attr_int, attr_ints, attr_string};
use crate::InputEncoder;
use crate::bundle::BundleFile;
use crate::input::resize_taps;
use crate::network::DenseDepth;
use sensor::gate::ContactGate;

/// The graph's input: the crop, `[crop, crop, 3]` uint8, R, G, B.
pub const FRAME: &str = "frame";
/// Depth (mm) on the crop, `[crop, crop]` float32.
pub const DEPTH_MM: &str = "depth_mm";
/// Whether the contact gate let the network run (bool scalar).
pub const CONTACT: &str = "contact";
/// With the pressure output: pressure (kPa) on the crop, and its resultant force (N, sensor
/// frame, `[3]`); with the force head, the head's force and the pressure scaled to its size
/// (the head's force alone where the network has no pressure output).
pub const PRESSURE_KPA: &str = "pressure_kpa";
pub const FORCE_N: &str = "force_n";

/// What the graph is made of: a bundle's network (folded, as `infer` runs it) and description,
/// and its unit's reference frame where the bundle has one (the balance, the gate, the
/// difference channels and the tare all read it).
pub struct WholePredictor<'a> {
    pub net: &'a DenseDepth,
    pub file: &'a BundleFile,
    pub reference: Option<&'a RgbImage>,
}

/// The balance's answer: the frame's planes with the drift undone, and the fitted gains.
struct Balanced {
    /// `[3, crop, crop]` float grey levels.
    planes: String,
    /// `[3, 1, 1]` the fitted gains and their inverses (1 where a channel keeps no gain), for
    /// the gate.
    gains: String,
    inverse: String,
    /// `[3, crop, crop]` bool: the frame's levels the camera clipped at 255.
    clipped: String,
}

/// The ONNX model of the whole predictor; see the module's description.
pub fn export_whole(p: &WholePredictor) -> Result<Vec<u8>, OnnxError> {
    let file = p.file;
    let s = file.sensor.crop_size_px as usize;
    let mask = file.sensor.valid_mask();
    let encoding = file.encoding().map_err(|why| OnnxError::Unsupported { what: "input_encoding".into(), why })?;
    let hw = [file.input_height_px, file.input_width_px];
    let encoder = InputEncoder::new(encoding, hw, p.reference)
        .map_err(|e| OnnxError::Unsupported { what: "the input".into(), why: e.to_string() })?;
    if let Some(r) = p.reference
        && r.dimensions() != (s as u32, s as u32)
    {
        let why = format!("the reference frame is {}x{}, the crop {s}x{s}", r.width(), r.height());
        return Err(OnnxError::Unsupported { what: "the reference".into(), why });
    }
    let net = p.net.clone().folded();
    let mut g = Graph::default();
    let perm = attr_ints("perm", &[2, 0, 1]);
    let levels = g.node("Transpose", "whole.planes_u8", &[FRAME], vec![perm]);
    let raw = g.cast("whole.planes", &levels, FLOAT);
    let balanced = p.reference.map(|reference| g.balance(&raw, reference, &mask));
    let gate = match (p.reference, &balanced, &file.contact_gate) {
        (Some(reference), Some(b), Some(record)) => Some(g.gate(&raw, b, reference, &mask, record.gate)),
        _ => None,
    };
    let planes = balanced.map_or(raw, |b| b.planes);
    let tare = p.reference.map(|r| tare(&net, file, &encoder, r));

    // The network's branch: everything from the encoding on.
    // Its constants go in the branch's own graph (tract names a subgraph's outer-scope inputs
    // after them, which collides with the names its translations give).
    let outer = std::mem::take(&mut g.nodes);
    let outer_constants = g.initializers.len();
    let input = g.encode(&planes, &encoder, s);
    let super::NetOutputs { depth, pressure, force: head } = g.densedepth(&net, &input)?;
    let out_hw = file.model.output_hw(hw);
    let trained = sensor::resample::covered_mask(&mask, s, out_hw);
    let fill = sensor::resample::FillPlan::new(&trained, out_hw);
    let scale = file.depth_scale;
    let mm = {
        let d = g.reshape("whole.depth.plane", &depth, &[out_hw[0] as i64, out_hw[1] as i64]);
        let [min, max, range] = [
            g.scalar("whole.scale.net_min", scale.net_min),
            g.scalar("whole.scale.max_mm", scale.max_depth_mm),
            g.scalar("whole.scale.range", scale.range()),
        ];
        let d = g.node("Sub", "whole.depth.shift", &[&d, &min], vec![]);
        let d = g.node("Mul", "whole.depth.times_max", &[&d, &max], vec![]);
        g.node("Div", "whole.depth.mm", &[&d, &range], vec![])
    };
    let depth = g.on_crop("whole.depth", &mm, tare.as_ref().map(|t| t.mm.as_slice()), &fill, out_hw, s);
    let depth = {
        let max = file.sensor.max_depth_mm as f32;
        let zero = g.scalar("whole.zero", 0.0);
        let top = g.scalar("whole.max_depth", max);
        let clamped = g.node("Clip", "whole.depth.clamped", &[&depth, &zero, &top], vec![]);
        let mask = g.bools("whole.mask", &[s as i64, s as i64], &mask);
        g.node("Where", "whole.depth.masked", &[&mask, &clamped, &zero], vec![])
    };
    let mut outputs = vec![(depth, DEPTH_MM, vec![s as i64, s as i64])];
    let head = head.map(|h| g.head_force(&h, &outputs[0].0, tare.as_ref().and_then(|t| t.force_n)));
    if let Some(pressure) = pressure {
        let [oh, ow] = out_hw.map(|v| v as i64);
        let p = g.reshape("whole.pressure.plane", &pressure, &[oh, ow]);
        let per = crate::PRESSURE_KPA_PER_UNIT;
        let per = g.scalar("whole.pressure.per_unit", per);
        let kpa = g.node("Mul", "whole.pressure.kpa", &[&p, &per], vec![]);
        let tare_kpa = tare.as_ref().and_then(|t| t.kpa.as_deref());
        let kpa = g.on_crop("whole.pressure", &kpa, tare_kpa, &fill, out_hw, s);
        let (pressure, force) = g.force(&outputs[0].0, &kpa, file, s);
        let (pressure, force) = match &head {
            Some(head) => (g.scaled_to(&pressure, &force, head), head.clone()),
            None => (pressure, force),
        };
        outputs.push((pressure, PRESSURE_KPA, vec![s as i64, s as i64]));
        outputs.push((force, FORCE_N, vec![3]));
    } else if let Some(head) = head {
        outputs.push((head, FORCE_N, vec![3]));
    }
    let branch = std::mem::replace(&mut g.nodes, outer);
    let branch_constants = g.initializers.split_off(outer_constants);

    let mut graph_outputs = Vec::new();
    match gate {
        Some(contact) => {
            // The else branch: zeros of each output's shape.
            let then_out: Vec<ValueInfoProto> = outputs.iter().map(|(v, _, d)| float_info(v, d)).collect();
            let mut else_nodes = Vec::new();
            let mut else_out = Vec::new();
            // (Named apart from the branch's own constants, which its graph holds.)
            let zero = g.scalar("whole.untouched.zero", 0.0);
            for (_, name, dims) in &outputs {
                let shape = g.ints(&format!("whole.untouched.{name}.shape"), &[dims.len() as i64], dims);
                let out = format!("whole.untouched.{name}");
                else_nodes.push(NodeProto {
                    input: vec![zero.clone(), shape],
                    output: vec![out.clone()],
                    name: out.clone(),
                    op_type: "Expand".into(),
                    attribute: vec![],
                });
                else_out.push(float_info(&out, dims));
            }
            let then_branch = GraphProto {
                node: branch,
                name: "network".into(),
                initializer: branch_constants,
                output: then_out,
                ..Default::default()
            };
            let else_branch =
                GraphProto { node: else_nodes, name: "untouched".into(), output: else_out, ..Default::default() };
            g.nodes.push(NodeProto {
                input: vec![contact.clone()],
                output: outputs.iter().map(|(_, name, _)| name.to_string()).collect(),
                name: "whole.gate".into(),
                op_type: "If".into(),
                attribute: vec![graph_attr("then_branch", then_branch), graph_attr("else_branch", else_branch)],
            });
            g.node("Identity", CONTACT, &[&contact], vec![]);
        }
        None => {
            g.nodes.extend(branch);
            g.initializers.extend(branch_constants);
            for (value, name, _) in &outputs {
                g.node("Identity", name, &[value], vec![]);
            }
            let yes = g.bools("whole.always", &[], &[true]);
            g.node("Identity", CONTACT, &[&yes], vec![]);
        }
    }
    for (_, name, dims) in &outputs {
        graph_outputs.push(float_info(name, dims));
    }
    graph_outputs.push(typed_info(CONTACT, BOOL, &[]));
    let graph = GraphProto {
        node: g.nodes,
        name: "densetact_predictor".into(),
        initializer: g.initializers,
        input: vec![typed_info(FRAME, UINT8, &[s as i64, s as i64, 3])],
        output: graph_outputs,
    };
    let doc = "DenseTact predictor: the sensor's crop (uint8 RGB) in, depth in mm on the crop out";
    Ok(super::model_bytes(graph, doc, super::metadata(file, net.decoder.pressure.is_some(), true)))
}

/// The network's outputs on the reference frame: what `infer` subtracts from every prediction.
struct Tare {
    /// Depth (mm), output grid.
    mm: Vec<f32>,
    /// Pressure (kPa), output grid, with the pressure output.
    kpa: Option<Vec<f32>>,
    /// The force head's force (N), with the head.
    force_n: Option<[f32; 3]>,
}

fn tare(net: &DenseDepth, file: &BundleFile, encoder: &InputEncoder, reference: &RgbImage) -> Tare {
    let device = net.encoder.conv0.weight.val().device();
    let [h, w] = encoder.hw();
    let c = encoder.channels().count();
    let x = Tensor::<4>::from_data(TensorData::new(encoder.encode(reference), [1, c, h, w]), &device);
    let heads = net.forward_heads(x);
    let values = |t: Tensor<4>| t.into_data().convert::<f32>().try_into_vec::<f32>().expect("f32 output");
    let mm = values(heads.depth).into_iter().map(|v| file.depth_scale.to_mm(v)).collect();
    let kpa = heads.pressure.map(|p| values(p).into_iter().map(|v| v * crate::PRESSURE_KPA_PER_UNIT).collect());
    let force_n = heads.force.map(|f| {
        let v = f.into_data().convert::<f32>().try_into_vec::<f32>().expect("f32 output");
        std::array::from_fn(|k| v[k] * crate::FORCE_N_PER_LOSS_UNIT)
    });
    Tare { mm, kpa, force_n }
}

fn typed_info(name: &str, elem_type: i32, dims: &[i64]) -> ValueInfoProto {
    let dim = dims.iter().map(|&d| Dimension { value: Some(DimensionValue::DimValue(d)) }).collect();
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TensorTypeProto { elem_type, shape: Some(TensorShapeProto { dim }) }),
        }),
    }
}

fn float_info(name: &str, dims: &[i64]) -> ValueInfoProto {
    typed_info(name, FLOAT, dims)
}

fn graph_attr(name: &str, g: GraphProto) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: ATTR_GRAPH, g: Some(g), ..Default::default() }
}

impl Graph {
    /// A constant, written once: a second call with the same name (which names its content)
    /// reuses the first.
    pub(super) fn tensor(&mut self, name: &str, dims: &[i64], data_type: i32, raw_data: Vec<u8>) -> String {
        if self.initializers.iter().any(|t| t.name == name) {
            return name.into();
        }
        self.initializers.push(TensorProto { dims: dims.to_vec(), data_type, name: name.into(), raw_data });
        name.into()
    }

    fn floats(&mut self, name: &str, dims: &[i64], values: &[f32]) -> String {
        self.tensor(name, dims, FLOAT, values.iter().flat_map(|v| v.to_le_bytes()).collect())
    }

    pub(super) fn ints(&mut self, name: &str, dims: &[i64], values: &[i64]) -> String {
        self.tensor(name, dims, INT64, values.iter().flat_map(|v| v.to_le_bytes()).collect())
    }

    fn bools(&mut self, name: &str, dims: &[i64], values: &[bool]) -> String {
        self.tensor(name, dims, BOOL, values.iter().map(|&b| u8::from(b)).collect())
    }

    pub(super) fn scalar(&mut self, name: &str, v: f32) -> String {
        self.floats(name, &[], &[v])
    }

    fn int(&mut self, name: &str, v: i64) -> String {
        self.ints(name, &[], &[v])
    }

    fn reshape(&mut self, name: &str, x: &str, dims: &[i64]) -> String {
        let shape = self.ints(&format!("{name}.shape"), &[dims.len() as i64], dims);
        self.node("Reshape", name, &[x, &shape], vec![])
    }

    fn cast(&mut self, name: &str, x: &str, to: i32) -> String {
        self.node("Cast", name, &[x], vec![attr_int("to", to as i64)])
    }

    /// How many of the `n` bin indices `bins` (int64 in [0, BALANCE_BINS)) fall in each bin:
    /// float counts (exact to 2^24).
    ///
    /// The counts are scattered into zeros at least as long as the indices, then cut to the
    /// bins: ONNX allows fewer bins than indices, but OpenCV's DNN module refuses a `Scatter`
    /// whose indices are longer than its data.
    fn histogram(&mut self, name: &str, bins: &str, n: usize) -> String {
        let bins_len = sensor::gate::BALANCE_BINS;
        let zero = self.scalar("whole.zero", 0.0);
        let one = self.scalar("whole.one", 1.0);
        // Room for one bin past the last: the samples the fit leaves out land there and are cut.
        let room_len = n.max(bins_len + 1);
        let room = self.ints(&format!("whole.balance.room_{room_len}"), &[1], &[room_len as i64]);
        let zeros = self.node("Expand", &format!("{name}.zeros"), &[&zero, &room], vec![]);
        let shape = self.ints(&format!("{name}.n"), &[1], &[n as i64]);
        let ones = self.node("Expand", &format!("{name}.ones"), &[&one, &shape], vec![]);
        let attrs = vec![attr_int("axis", 0), attr_string("reduction", "add")];
        let counts = self.node("ScatterElements", &format!("{name}.roomy"), &[&zeros, bins, &ones], attrs);
        let [start, end, axis] = [
            self.ints("whole.int.[0]", &[1], &[0]),
            self.ints(&format!("whole.int.[{bins_len}]"), &[1], &[bins_len as i64]),
            self.ints("whole.axes.0", &[1], &[0]),
        ];
        self.node("Slice", name, &[&counts, &start, &end, &axis], vec![])
    }

    /// The first bin (int64 scalar) whose running count of `counts`, less `before` (the count
    /// before a window), reaches half of `total` (`2 x seen >= total`, as the fit's median):
    /// the number of bins that fall short.
    fn first_reaching_half(&mut self, name: &str, counts: &str, before: Option<&str>, total: &str) -> String {
        let axis = self.int("whole.int.0", 0);
        let mut seen = self.node("CumSum", &format!("{name}.seen"), &[counts, &axis], vec![]);
        if let Some(before) = before {
            seen = self.node("Sub", &format!("{name}.seen_in_window"), &[&seen, before], vec![]);
        }
        let twice = self.node("Add", &format!("{name}.twice"), &[&seen, &seen], vec![]);
        let short = self.node("Less", &format!("{name}.short"), &[&twice, total], vec![]);
        let short = self.cast(&format!("{name}.short_f"), &short, FLOAT);
        let k = self.node("ReduceSum", &format!("{name}.k"), &[&short], vec![attr_int("keepdims", 0)]);
        self.cast(name, &k, INT64)
    }

    /// x rounded to the nearest integer, halves up (Rust's `round` on the non-negative values
    /// it is used on; ONNX's `Round` takes halves to even).
    fn round_half_up(&mut self, name: &str, x: &str) -> String {
        let floor = self.node("Floor", &format!("{name}.floor"), &[x], vec![]);
        let frac = self.node("Sub", &format!("{name}.frac"), &[x, &floor], vec![]);
        let half = self.scalar("whole.half", 0.5);
        let up = self.node("GreaterOrEqual", &format!("{name}.up"), &[&frac, &half], vec![]);
        let up = self.cast(&format!("{name}.up_f32"), &up, FLOAT);
        self.node("Add", name, &[&floor, &up], vec![])
    }

    /// The grey level (0..=255, as a float) nearest x, halves up: what the Rust code gets by
    /// rounding and clamping a level, in either order (both integral bounds).
    fn grey_level(&mut self, name: &str, x: &str) -> String {
        let rounded = self.round_half_up(&format!("{name}.rounded"), x);
        let (zero, top) = (self.scalar("whole.zero", 0.0), self.scalar("whole.level.max", 255.0));
        self.node("Clip", name, &[&rounded, &zero, &top], vec![])
    }

    /// The reference frame's planes, `[3, crop, crop]` float grey levels: one constant for the
    /// balance and the gate.
    fn reference_planes(&mut self, reference: &RgbImage) -> String {
        let n = reference.width() as i64;
        let q: Vec<f32> = (0..3).flat_map(|c| reference.pixels().map(move |p| p.0[c] as f32)).collect();
        self.floats("whole.reference", &[3, n, n], &q)
    }

    /// The frame's drift against `reference` taken out, as `Balance::fit` then `undo` do; the
    /// gains are kept for the gate.
    /// `raw`: the frame's planes, `[3, crop, crop]` float grey levels.
    fn balance(&mut self, raw: &str, reference: &RgbImage, mask: &[bool]) -> Balanced {
        use sensor::gate::*;
        let n_px = mask.len();
        let flat = self.reshape("whole.balance.flat", raw, &[3 * n_px as i64]);
        // Ratios binned and bins turned into gains by tables the fit's own functions fill, so
        // that no runtime's division (tract multiplies by a reciprocal) moves a bin.
        // (A reference level of 0 is never sampled: its entries are 0.)
        let table: Vec<i64> = balance_bin_table()
            .iter()
            .enumerate()
            .map(|(i, &bin)| if i >> 8 == 0 { 0 } else { i64::from(bin) })
            .collect();
        let bin_table = self.ints("whole.balance.bin_table", &[table.len() as i64], &table);
        let gain_table: Vec<f32> = (0..BALANCE_BINS).map(balance_gain).collect();
        let gain_table = self.floats("whole.balance.gain_table", &[BALANCE_BINS as i64], &gain_table);
        // Each bin's inverse gain, as `undo_level` is given it (the last entry: no gain).
        let inverses: Vec<f32> =
            (0..=BALANCE_BINS).map(|b| if b == BALANCE_BINS { 1.0 } else { 1.0 / balance_gain(b) }).collect();
        let inverses = self.floats("whole.balance.inverses", &[inverses.len() as i64], &inverses);
        let no_gain = self.ints("whole.balance.no_gain_bin", &[1], &[BALANCE_BINS as i64]);
        let (mut gains, mut undo_bins) = (Vec::new(), Vec::new());
        for c in 0..3 {
            let name = format!("whole.balance.{c}");
            let (idx, q): (Vec<i64>, Vec<u8>) = reference
                .pixels()
                .enumerate()
                .filter(|(i, p)| Balance::samples(*i, mask[*i], p.0[c]))
                .map(|(i, p)| ((c * n_px + i) as i64, p.0[c]))
                .unzip();
            let n = idx.len();
            if (n as u32) < BALANCE_MIN_SAMPLES {
                gains.push(self.floats("whole.one1", &[1], &[1.0]));
                undo_bins.push(no_gain.clone());
                continue;
            }
            let idx = self.ints(&format!("{name}.idx"), &[n as i64], &idx);
            // Each sample's row of the table: its reference value times 256.
            let starts: Vec<i64> = q.iter().map(|&q| q as i64 * 256).collect();
            let starts = self.ints(&format!("{name}.table_rows"), &[n as i64], &starts);
            // The samples' levels, gathered as floats and cast: the whole frame is never cast.
            let p_f = self.node("Gather", &format!("{name}.frame_f"), &[&flat, &idx], vec![]);
            let p = self.cast(&format!("{name}.frame"), &p_f, INT64);
            let at = self.node("Add", &format!("{name}.table_at"), &[&p, &starts], vec![]);
            let bins = self.node("Gather", &format!("{name}.bins"), &[&bin_table, &at], vec![]);
            // The frame's clipped levels are left out: their bin (and below, their deviation) is
            // one past the last, which the histograms cut; the totals count the rest.
            let top = self.scalar("whole.level.max", 255.0);
            let clipped = self.node("GreaterOrEqual", &format!("{name}.clipped"), &[&p_f, &top], vec![]);
            let beyond = self.int("whole.balance.beyond_bin", BALANCE_BINS as i64);
            let bins = self.node("Where", &format!("{name}.bins_kept"), &[&clipped, &beyond, &bins], vec![]);
            let kept = self.node("Less", &format!("{name}.kept"), &[&p_f, &top], vec![]);
            let kept = self.cast(&format!("{name}.kept_f"), &kept, FLOAT);
            let total = self.node("ReduceSum", &format!("{name}.total"), &[&kept], vec![attr_int("keepdims", 0)]);
            // The fit's histogram, and its median: the first bin whose running count reaches half.
            let counts = self.histogram(&format!("{name}.counts"), &bins, n);
            let m = self.first_reaching_half(&format!("{name}.median"), &counts, None, &total);
            // The median absolute deviation: the same over the deviations' histogram.
            // |bins - m| as the larger of the two differences: OpenCV's `Abs` takes floats only.
            let up = self.node("Sub", &format!("{name}.dev"), &[&bins, &m], vec![]);
            let down = self.node("Sub", &format!("{name}.dev_down"), &[&m, &bins], vec![]);
            let dev = self.node("Max", &format!("{name}.absdev_all"), &[&up, &down], vec![]);
            let dev = self.node("Where", &format!("{name}.absdev"), &[&clipped, &beyond, &dev], vec![]);
            let dev_counts = self.histogram(&format!("{name}.dev_counts"), &dev, n);
            let mad = self.first_reaching_half(&format!("{name}.mad"), &dev_counts, None, &total);
            // reach = max(ceil(sigmas x mad x mad_to_sigma), min): in integers, as the f64 product
            // of an integer and 4.4478 is never within rounding of a whole number.
            let times = (TRIM_SIGMAS * MAD_TO_SIGMA * 10_000.0).round() as i64;
            let [times, ten_k, up, min_reach] = [
                self.int("whole.balance.trim_x10000", times),
                self.int("whole.int.10000", 10_000),
                self.int("whole.int.9999", 9_999),
                self.int("whole.balance.min_reach", TRIM_MIN_BINS as i64),
            ];
            let r = self.node("Mul", &format!("{name}.reach_x10000"), &[&mad, &times], vec![]);
            let r = self.node("Add", &format!("{name}.reach_up"), &[&r, &up], vec![]);
            let r = self.node("Div", &format!("{name}.reach_ceil"), &[&r, &ten_k], vec![]);
            let reach = self.node("Max", &format!("{name}.reach"), &[&r, &min_reach], vec![]);
            let [zero_i, last_i] =
                [self.int("whole.int.0", 0), self.int("whole.balance.last_bin_i", BALANCE_BINS as i64 - 1)];
            let lo = self.node("Sub", &format!("{name}.lo_raw"), &[&m, &reach], vec![]);
            let lo = self.node("Max", &format!("{name}.lo_i"), &[&lo, &zero_i], vec![]);
            let hi = self.node("Add", &format!("{name}.hi_raw"), &[&m, &reach], vec![]);
            let hi = self.node("Min", &format!("{name}.hi_i"), &[&hi, &last_i], vec![]);
            let below = self.node("Less", &format!("{name}.below"), &[&bins, &lo], vec![]);
            let below = self.cast(&format!("{name}.below_f"), &below, FLOAT);
            let below = self.node("ReduceSum", &format!("{name}.n_below"), &[&below], vec![attr_int("keepdims", 0)]);
            let above_lo = self.node("GreaterOrEqual", &format!("{name}.from_lo"), &[&bins, &lo], vec![]);
            let under_hi = self.node("LessOrEqual", &format!("{name}.to_hi"), &[&bins, &hi], vec![]);
            let inside = self.node("And", &format!("{name}.inside"), &[&above_lo, &under_hi], vec![]);
            let inside = self.cast(&format!("{name}.inside_f"), &inside, FLOAT);
            let inside = self.node("ReduceSum", &format!("{name}.n_inside"), &[&inside], vec![attr_int("keepdims", 0)]);
            // The window's median: its first bin whose count (from the window's start) reaches
            // half the window's.
            let trimmed = self.first_reaching_half(&format!("{name}.trimmed"), &counts, Some(&below), &inside);
            let gain = self.node("Gather", &format!("{name}.gain_fitted"), &[&gain_table, &trimmed], vec![]);
            // Too few samples left: no gain, as the fit keeps 1.
            let min_samples = self.scalar("whole.balance.min_samples", BALANCE_MIN_SAMPLES as f32);
            let few = self.node("Less", &format!("{name}.few"), &[&total, &min_samples], vec![]);
            let one = self.scalar("whole.one", 1.0);
            let gain = self.node("Where", &format!("{name}.gain_scalar"), &[&few, &one, &gain], vec![]);
            let no_gain_scalar = self.int("whole.balance.no_gain_bin_scalar", BALANCE_BINS as i64);
            let trimmed =
                self.node("Where", &format!("{name}.undo_bin_scalar"), &[&few, &no_gain_scalar, &trimmed], vec![]);
            undo_bins.push(self.reshape(&format!("{name}.undo_bin"), &trimmed, &[1]));
            gains.push(self.reshape(&format!("{name}.gain"), &gain, &[1]));
        }
        let refs: Vec<&str> = gains.iter().map(|s| s.as_str()).collect();
        let gains = self.node("Concat", "whole.balance.gains3", &refs, vec![attr_int("axis", 0)]);
        let gains = self.reshape("whole.balance.gains", &gains, &[3, 1, 1]);
        // No drift worth undoing: every gain within NO_DRIFT of 1.
        let one = self.scalar("whole.one", 1.0);
        let off = self.node("Sub", "whole.balance.off", &[&gains, &one], vec![]);
        let off = self.node("Abs", "whole.balance.abs_off", &[&off], vec![]);
        let off = self.node("ReduceMax", "whole.balance.max_off", &[&off], vec![attr_int("keepdims", 0)]);
        let tol = self.scalar("whole.balance.no_drift", NO_DRIFT);
        let none = self.node("Less", "whole.balance.none", &[&off, &tol], vec![]);
        // The undo, as `undo_level` computes it: each channel's inverse gain (its bin's, or none
        // where there is no drift) times every level, one float32 product each (exactly Rust's),
        // rounded halves up and kept in range.
        let refs: Vec<&str> = undo_bins.iter().map(|s| s.as_str()).collect();
        let undo_bins = self.node("Concat", "whole.balance.undo_bins3", &refs, vec![attr_int("axis", 0)]);
        // The gate undoes the fitted drift whether or not the input does, as `Balance::comparison`.
        let fitted = self.node("Gather", "whole.balance.fitted_inverse3", &[&inverses, &undo_bins], vec![]);
        let fitted = self.reshape("whole.balance.fitted_inverse", &fitted, &[3, 1, 1]);
        let undo_bins = self.node("Where", "whole.balance.undo_bins_used", &[&none, &no_gain, &undo_bins], vec![]);
        let inverse = self.node("Gather", "whole.balance.inverse3", &[&inverses, &undo_bins], vec![]);
        let inverse = self.reshape("whole.balance.inverse", &inverse, &[3, 1, 1]);
        let scaled = self.node("Mul", "whole.balance.scaled", &[raw, &inverse], vec![]);
        let planes = self.grey_level("whole.balance.undone", &scaled);
        // A level the camera clipped reads as the reference where that is brighter.
        let q = self.reference_planes(reference);
        let lifted = self.node("Max", "whole.balance.lifted", &[&planes, &q], vec![]);
        let top = self.scalar("whole.level.max", 255.0);
        let clipped = self.node("GreaterOrEqual", "whole.balance.clipped", &[raw, &top], vec![]);
        let planes = self.node("Where", "whole.balance.planes", &[&clipped, &lifted, &planes], vec![]);
        Balanced { planes, gains, inverse: fitted, clipped }
    }

    /// Whether the frame differs from the reference by more than the unit's noise (the contact
    /// gate, `ContactGate::differs`): a bool scalar.
    /// `raw` is the frame's planes as they came, `balanced` the balance's fit of them.
    fn gate(
        &mut self,
        raw: &str,
        balanced: &Balanced,
        reference: &RgbImage,
        mask: &[bool],
        gate: ContactGate,
    ) -> String {
        let n = reference.width() as i64;
        let q = self.reference_planes(reference);
        // As `Comparison::difference` compares: frame and reference brought to the brighter
        // exposure (the frame times the inverse gain where that is above 1, the reference times
        // the gain where that is), a clipped level lifted to the reference where that is brighter.
        let one = self.scalar("whole.one", 1.0);
        let a = self.node("Max", "whole.gate.frame_scale", &[&balanced.inverse, &one], vec![]);
        let b = self.node("Max", "whole.gate.reference_scale", &[&balanced.gains, &one], vec![]);
        let level = self.node("Mul", "whole.gate.frame", &[raw, &a], vec![]);
        let q = self.node("Mul", "whole.gate.reference", &[&q, &b], vec![]);
        let lifted = self.node("Max", "whole.gate.lifted", &[&level, &q], vec![]);
        let level = self.node("Where", "whole.gate.levels", &[&balanced.clipped, &lifted, &level], vec![]);
        let d = self.node("Sub", "whole.gate.diff", &[&level, &q], vec![]);
        let d = self.node("Abs", "whole.gate.absdiff", &[&d], vec![]);
        let axis = self.ints("whole.axes.0", &[1], &[0]);
        let mut channels = Vec::new();
        for c in 0..3i64 {
            let a = self.ints(&format!("whole.int.[{c}]"), &[1], &[c]);
            let b = self.ints(&format!("whole.int.[{}]", c + 1), &[1], &[c + 1]);
            channels.push(self.node("Slice", &format!("whole.gate.channel{c}"), &[&d, &a, &b, &axis], vec![]));
        }
        // Summed as the gate sums: red, then green, then blue.
        let sum = self.node("Add", "whole.gate.rg", &[&channels[0], &channels[1]], vec![]);
        let sum = self.node("Add", "whole.gate.rgb", &[&sum, &channels[2]], vec![]);
        let limit = gate.grey_levels * 3.0;
        let limit = self.scalar("whole.gate.limit", limit);
        let over = self.node("Greater", "whole.gate.over", &[&sum, &limit], vec![]);
        let useful = self.bools("whole.gate.mask", &[1, n, n], mask);
        let changed = self.node("And", "whole.gate.changed", &[&over, &useful], vec![]);
        let changed = self.cast("whole.gate.changed_i", &changed, INT64);
        let count = self.node("ReduceSum", "whole.gate.count", &[&changed], vec![attr_int("keepdims", 0)]);
        let min = self.int("whole.gate.min_pixels", gate.min_pixels as i64);
        self.node("GreaterOrEqual", "whole.gate.contact", &[&count, &min], vec![])
    }

    /// `x` (`[3, h, w]`) resampled along `axis` by `taps` as the `image` crate sums them: tap by
    /// tap, each a product added in order, so that the sums (and their rounding to grey levels)
    /// are its sums bit for bit; a matrix product would reorder them and flip a rounding now and
    /// then. Outputs with fewer taps than the most are padded with zero weights.
    fn taps(&mut self, name: &str, x: &str, axis: usize, taps: &[(usize, Vec<f32>)]) -> String {
        let longest = taps.iter().map(|(_, w)| w.len()).max().unwrap_or(0);
        let n = taps.len() as i64;
        let dims: Vec<i64> = if axis == 1 { vec![n, 1] } else { vec![n] };
        let mut sum: Option<String> = None;
        for k in 0..longest {
            let idx: Vec<i64> = taps.iter().map(|(lo, w)| (lo + k.min(w.len() - 1)) as i64).collect();
            let weights: Vec<f32> = taps.iter().map(|(_, w)| w.get(k).copied().unwrap_or(0.0)).collect();
            let idx = self.ints(&format!("{name}.{k}.from"), &[n], &idx);
            let weights = self.floats(&format!("{name}.{k}.weights"), &dims, &weights);
            let got =
                self.node("Gather", &format!("{name}.{k}.pixels"), &[x, &idx], vec![attr_int("axis", axis as i64)]);
            let product = self.node("Mul", &format!("{name}.{k}.weighted"), &[&got, &weights], vec![]);
            sum = Some(match sum {
                None => product,
                Some(s) => self.node("Add", &format!("{name}.{k}.sum"), &[&s, &product], vec![]),
            });
        }
        sum.expect("at least one tap")
    }

    /// The network's input `[1, C, h, w]` from the balanced planes: resized (the `image`
    /// crate's taps, vertical then horizontal, rounded), / 255, and the reference difference.
    fn encode(&mut self, planes: &str, encoder: &InputEncoder, s: usize) -> String {
        let [h, w] = encoder.hw();
        let mut x = planes.to_string();
        if [h, w] != [s, s] {
            x = self.taps("whole.resize.vertical", &x, 1, &resize_taps(s, h));
            x = self.taps("whole.resize.horizontal", &x, 2, &resize_taps(s, w));
            x = self.grey_level("whole.resize.levels", &x);
        }
        // Grey levels / 255 by a table, as exact as the division (no runtime's reciprocal).
        let table: Vec<f32> = (0..=255u8).map(|v| v as f32 / 255.0).collect();
        let table = self.floats("whole.input.level_table", &[256], &table);
        let x = self.cast("whole.input.levels", &x, INT64);
        let rgb = self.node("Gather", "whole.input.rgb", &[&table, &x], vec![]);
        let mut input = rgb.clone();
        if let Some(reference) = encoder.reference_planes() {
            let r = self.floats("whole.input.reference", &[3, h as i64, w as i64], reference);
            let gain = encoder.encoding().difference_gain;
            let gain = self.scalar("whole.input.difference_gain", gain);
            let d = self.node("Sub", "whole.input.change", &[&rgb, &r], vec![]);
            let d = self.node("Mul", "whole.input.difference", &[&gain, &d], vec![]);
            input = self.node("Concat", "whole.input.channels", &[&rgb, &d], vec![attr_int("axis", 0)]);
        }
        let c = encoder.channels().count() as i64;
        self.reshape("whole.input", &input, &[1, c, h as i64, w as i64])
    }

    /// One output plane (`[oh, ow]`) on the crop: `tare` subtracted, the untrained border filled
    /// ring by ring, resized to `[s, s]`: `Predictor::on_crop`.
    fn on_crop(
        &mut self,
        name: &str,
        plane: &str,
        tare: Option<&[f32]>,
        fill: &sensor::resample::FillPlan,
        [oh, ow]: [usize; 2],
        s: usize,
    ) -> String {
        let mut x = plane.to_string();
        if let Some(tare) = tare {
            let t = self.floats(&format!("{name}.tare"), &[oh as i64, ow as i64], tare);
            x = self.node("Sub", &format!("{name}.tared"), &[&x, &t], vec![]);
        }
        let n = (oh * ow) as i64;
        x = self.reshape(&format!("{name}.flat"), &x, &[n]);
        let zero = self.floats("whole.zero1", &[1], &[0.0]);
        for (k, ring) in fill.rings().enumerate() {
            let r = format!("{name}.fill{k}");
            let width = ring.iter().map(|(_, from)| from.len()).max().unwrap_or(1);
            // Each pixel's known neighbours, padded with the appended zero (index n).
            let mut idx = vec![n; ring.len() * width];
            for (row, (_, from)) in ring.iter().enumerate() {
                for (j, &f) in from.iter().enumerate() {
                    idx[row * width + j] = f as i64;
                }
            }
            let counts: Vec<f32> = ring.iter().map(|(_, from)| from.len() as f32).collect();
            let targets: Vec<i64> = ring.iter().map(|(i, _)| *i as i64).collect();
            let rows = ring.len() as i64;
            let idx = self.ints(&format!("{r}.from"), &[rows, width as i64], &idx);
            let counts = self.floats(&format!("{r}.counts"), &[rows], &counts);
            let targets = self.ints(&format!("{r}.targets"), &[rows, 1], &targets);
            let ext = self.node("Concat", &format!("{r}.padded"), &[&x, &zero], vec![attr_int("axis", 0)]);
            let got = self.node("Gather", &format!("{r}.neighbours"), &[&ext, &idx], vec![]);
            let axes = self.ints("whole.axes.1", &[1], &[1]);
            let sum = self.node("ReduceSum", &format!("{r}.sum"), &[&got, &axes], vec![attr_int("keepdims", 0)]);
            let mean = self.node("Div", &format!("{r}.mean"), &[&sum, &counts], vec![]);
            x = self.node("ScatterND", &format!("{r}.filled"), &[&x, &targets, &mean], vec![]);
        }
        x = self.reshape(&format!("{name}.filled"), &x, &[oh as i64, ow as i64]);
        let dense = |n_in: usize, n_out: usize| {
            let mut m = vec![0f32; n_out * n_in];
            for (o, (lo, ws)) in sensor::resample::triangle_weights(n_in, n_out).iter().enumerate() {
                m[o * n_in + lo..o * n_in + lo + ws.len()].copy_from_slice(ws);
            }
            m
        };
        // Rows first, as `resize_plane` resizes them.
        let across =
            self.floats(&format!("{name}.up_across"), &[ow as i64, s as i64], &transpose(&dense(ow, s), s, ow));
        let down = self.floats(&format!("{name}.up_down"), &[s as i64, oh as i64], &dense(oh, s));
        let rows = self.node("MatMul", &format!("{name}.up_rows"), &[&x, &across], vec![]);
        self.node("MatMul", &format!("{name}.on_crop"), &[&down, &rows], vec![])
    }

    /// Where `depth` (the crop's, in mm) shows contact: the one comparison the pressure and the
    /// force head both read, made once.
    fn touched(&mut self, depth: &str) -> String {
        const TOUCHED: &str = "whole.touched";
        if !self.nodes.iter().any(|n| n.name == TOUCHED) {
            let threshold = self.scalar("whole.contact_threshold_mm", sensor::CONTACT_THRESHOLD_MM);
            self.node("Greater", TOUCHED, &[depth, &threshold], vec![]);
        }
        TOUCHED.into()
    }

    /// Pressure kept where the depth shows contact (never negative), and its resultant force.
    fn force(&mut self, depth: &str, kpa: &str, file: &BundleFile, s: usize) -> (String, String) {
        let zero = self.scalar("whole.zero", 0.0);
        let touched = self.touched(depth);
        let pushing = self.node("Max", "whole.pressure.pushing", &[kpa, &zero], vec![]);
        let pressure = self.node("Where", "whole.pressure.kept", &[&touched, &pushing, &zero], vec![]);
        let n = (s * s) as i64;
        let per_kpa = sensor::DomeAreas::new(&file.sensor).force_per_kpa([s, s]);
        let per_kpa = transpose(&per_kpa, 3, s * s);
        let per_kpa = self.floats("whole.force.per_kpa", &[n, 3], &per_kpa);
        let flat = self.reshape("whole.force.pressure_row", &pressure, &[1, n]);
        let force = self.node("MatMul", "whole.force.sum", &[&flat, &per_kpa], vec![]);
        let force = self.reshape("whole.force", &force, &[3]);
        (pressure, force)
    }

    /// The force head's force (`[1, 3]`, N) as `infer` reports it: less its reading of the
    /// reference frame (`tare_n`), and zero where the depth shows no contact.
    fn head_force(&mut self, head: &str, depth: &str, tare_n: Option<[f32; 3]>) -> String {
        let f = self.reshape("whole.head.force", head, &[3]);
        let f = match tare_n {
            Some(t) => {
                let t = self.floats("whole.head.tare_n", &[3], &t);
                self.node("Sub", "whole.head.tared", &[&f, &t], vec![])
            }
            None => f,
        };
        let touched = self.touched(depth);
        let touched = self.node("Cast", "whole.head.touched_float", &[&touched], vec![attr_int("to", FLOAT as i64)]);
        let any = self.node("ReduceMax", "whole.head.any_contact", &[&touched], vec![attr_int("keepdims", 0)]);
        self.node("Mul", "whole.head.force_n", &[&f, &any], vec![])
    }

    /// `pressure` scaled so that its resultant's size is `head`'s: the map's shape, the head's
    /// total (`infer`'s `Force::scaled_to`).
    fn scaled_to(&mut self, pressure: &str, resultant: &str, head: &str) -> String {
        let keep = vec![attr_int("keepdims", 0)];
        let map_n = self.node("ReduceL2", "whole.head.map_n", &[resultant], keep.clone());
        let head_n = self.node("ReduceL2", "whole.head.head_n", &[head], keep);
        let tiny = self.scalar("whole.head.tiny_n", f32::MIN_POSITIVE);
        let map_n = self.node("Max", "whole.head.map_n_floor", &[&map_n, &tiny], vec![]);
        let ratio = self.node("Div", "whole.head.ratio", &[&head_n, &map_n], vec![]);
        self.node("Mul", "whole.head.pressure_kpa", &[pressure, &ratio], vec![])
    }
}

/// A row-major `[rows, cols]` matrix transposed.
fn transpose(m: &[f32], rows: usize, cols: usize) -> Vec<f32> {
    let mut t = vec![0f32; m.len()];
    for r in 0..rows {
        for c in 0..cols {
            t[c * rows + r] = m[r * cols + c];
        }
    }
    t
}
