//! A bundle's network as an ONNX graph (opset 17), weights embedded, for runtimes outside Rust
//! (ONNX Runtime, TensorRT, tract).
//!
//! The graph is the folded network `infer` runs, node for node: BatchNorms after convolutions
//! folded into them, the rest as `BatchNormalization`; transitions pool before their 1x1
//! convolution (the two commute exactly); every up block resizes (bilinear, align_corners) to
//! its skip's own size, read from the skip's shape at run time. So batch, height and width are
//! all free (`batch`, `height`, `width`); the bundle's input size is in the metadata.
//! Input `input` [batch, C, H, W]: the bundle's input encoding (RGB / 255, then the reference
//! difference if the model reads it). Output `depth` [batch, 1, h, w]: network depth units,
//! turned into millimetres by the metadata's `depth_scale`; with the pressure output,
//! `pressure` beside it; with the force head, `force` [batch, 3] in N (sensor frame).

mod proto;
mod whole;

pub use whole::{CONTACT, DEPTH_MM, FORCE_N, FRAME, PRESSURE_KPA, WholePredictor, export_whole};

use burn::nn::conv::Conv2d;
use burn::nn::{BatchNorm, PaddingConfig2d};
use burn::tensor::Tensor;
use prost::Message;

use crate::bundle::BundleFile;
use crate::network::{DenseBlock, DenseDepth, LEAKY_SLOPE, Transition, UpBlock};
use proto::*;

/// The opset the graph is written for.
pub const OPSET: i64 = 17;
/// Names of the graph's input and output.
pub const INPUT: &str = "input";
pub const OUTPUT: &str = "depth";
/// The second output's name, where the network has the pressure output (network units:
/// `densetact.pressure_kpa_per_unit` kPa each).
pub const PRESSURE_OUTPUT: &str = "pressure";
/// The force head's output, where the network has one: `[batch, 3]`, N, sensor frame.
pub const FORCE_OUTPUT: &str = "force";

/// The network's outputs' value names.
struct NetOutputs {
    depth: String,
    pressure: Option<String>,
    /// The force head's, in N.
    force: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("cannot export {what} to ONNX: {why}")]
    Unsupported { what: String, why: String },
}

/// The ONNX model of `net` (folded first, as inference runs it) with `file`'s description in
/// its metadata: `densetact.input_encoding`, `densetact.depth_scale`, `densetact.model`,
/// `densetact.input_hw`, `densetact.sensor`.
pub fn export(net: &DenseDepth, file: &BundleFile) -> Result<Vec<u8>, OnnxError> {
    let net = net.clone().folded();
    let mut g = Graph::default();
    let NetOutputs { depth, pressure, force } = g.densedepth(&net, INPUT)?;
    let channels = net.encoder.conv0.weight.dims()[1] as i64;
    let free = |name: &str| Dimension { value: Some(DimensionValue::DimParam(name.into())) };
    let fixed = |n: i64| Dimension { value: Some(DimensionValue::DimValue(n)) };
    let value = |name: &str, dims: Vec<Dimension>| ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TensorTypeProto { elem_type: FLOAT, shape: Some(TensorShapeProto { dim: dims }) }),
        }),
    };
    let out_dims = |h: &str, w: &str| vec![free("batch"), fixed(1), free(h), free(w)];
    let (oh, ow) = if file.model.full_resolution { ("height", "width") } else { ("out_height", "out_width") };
    g.rename_output(&depth, OUTPUT);
    let mut output = vec![value(OUTPUT, out_dims(oh, ow))];
    if let Some(p) = &pressure {
        g.rename_output(p, PRESSURE_OUTPUT);
        output.push(value(PRESSURE_OUTPUT, out_dims(oh, ow)));
    }
    if let Some(f) = &force {
        g.rename_output(f, FORCE_OUTPUT);
        output.push(value(FORCE_OUTPUT, vec![free("batch"), fixed(3)]));
    }
    let graph = GraphProto {
        node: g.nodes,
        name: "densedepth".into(),
        initializer: g.initializers,
        input: vec![value(INPUT, vec![free("batch"), fixed(channels), free("height"), free("width")])],
        output,
    };
    let doc = "DenseDepth for a DenseTact sensor: camera crop in, depth in network units out";
    Ok(model_bytes(graph, doc, metadata(file, pressure.is_some(), false)))
}

/// The metadata both exports carry: how the bundle reads frames and scales depth, its sensor;
/// for the whole predictor, also the crop rule, so that a full camera frame is cut as `infer`
/// cuts it.
fn metadata(file: &BundleFile, pressure: bool, whole: bool) -> Vec<(&'static str, String)> {
    let mut metadata = vec![
        ("densetact.input_encoding", file.input_encoding.clone()),
        ("densetact.depth_scale", json(&file.depth_scale)),
        ("densetact.model", json(&file.model)),
        ("densetact.input_hw", format!("{}x{}", file.input_height_px, file.input_width_px)),
        ("densetact.sensor", json(&file.sensor)),
    ];
    if pressure {
        metadata.push(("densetact.pressure_kpa_per_unit", crate::PRESSURE_KPA_PER_UNIT.to_string()));
    }
    if whole {
        let s = &file.sensor;
        let (x0, y0) = s.crop_origin_px();
        let crop = serde_json::json!({
            "size_px": s.crop_size_px,
            "origin_px": [x0, y0],
            "frame_px": [s.frame_width_px, s.frame_height_px],
            "rule": "x0 = round(centre_u_px - size_px / 2 + 0.5), y0 = round(centre_v_px - size_px / 2 + 0.5) \
                     (the sensor's calibrated optical centre); the crop is frame[y0 : y0 + size_px, x0 : x0 + size_px]",
        });
        metadata.push(("densetact.crop", crop.to_string()));
    }
    metadata
}

fn model_bytes(graph: GraphProto, doc: &str, metadata: Vec<(&str, String)>) -> Vec<u8> {
    let model = ModelProto {
        ir_version: IR_VERSION,
        opset_import: vec![OperatorSetIdProto { domain: String::new(), version: OPSET }],
        producer_name: "densetact-rs".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        doc_string: doc.into(),
        graph: Some(graph),
        metadata_props: metadata
            .into_iter()
            .map(|(key, value)| StringStringEntryProto { key: key.into(), value })
            .collect(),
    };
    model.encode_to_vec()
}

/// A bundle description's part as JSON, for the metadata.
fn json<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_string(value).expect("bundle descriptions serialise")
}

fn attr_ints(name: &str, ints: &[i64]) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: ATTR_INTS, ints: ints.to_vec(), ..Default::default() }
}

fn attr_int(name: &str, i: i64) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: ATTR_INT, i: Some(i), ..Default::default() }
}

fn attr_float(name: &str, f: f32) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: ATTR_FLOAT, f: Some(f), ..Default::default() }
}

fn attr_string(name: &str, s: &str) -> AttributeProto {
    AttributeProto { name: name.into(), r#type: ATTR_STRING, s: s.as_bytes().to_vec(), ..Default::default() }
}

/// Nodes and initializers being written; values are named by the module path that made them.
#[derive(Default)]
struct Graph {
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
}

impl Graph {
    fn node(&mut self, op: &str, name: &str, inputs: &[&str], attribute: Vec<AttributeProto>) -> String {
        let output = name.to_string();
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.clone()],
            name: name.into(),
            op_type: op.into(),
            attribute,
        });
        output
    }

    /// The last node's output takes the graph output's name.
    fn rename_output(&mut self, from: &str, to: &str) {
        for node in &mut self.nodes {
            for o in node.output.iter_mut().filter(|o| *o == from) {
                *o = to.into();
            }
        }
    }

    fn weight<const D: usize>(&mut self, name: &str, t: Tensor<D>) -> String {
        let dims = t.dims().iter().map(|&d| d as i64).collect();
        let values = t.into_data().convert::<f32>().try_into_vec::<f32>().expect("f32 weights");
        let raw_data = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.initializers.push(TensorProto { dims, data_type: FLOAT, name: name.into(), raw_data });
        name.into()
    }

    /// A constant int64 vector, written once however often it is asked for.
    fn int64s(&mut self, name: &str, values: &[i64]) -> String {
        self.ints(name, &[values.len() as i64], values)
    }

    fn conv(&mut self, name: &str, conv: &Conv2d, x: &str) -> Result<String, OnnxError> {
        let pads = match conv.padding {
            PaddingConfig2d::Valid => [0, 0, 0, 0],
            // ONNX's order is ours: top, left, bottom, right.
            PaddingConfig2d::Explicit(t, l, b, r) => [t, l, b, r].map(|p| p as i64),
            PaddingConfig2d::Same => {
                return Err(OnnxError::Unsupported { what: name.into(), why: "`Same` padding".into() });
            }
        };
        let w = self.weight(&format!("{name}.weight"), conv.weight.val());
        let mut inputs = vec![x.to_string(), w];
        if let Some(b) = &conv.bias {
            inputs.push(self.weight(&format!("{name}.bias"), b.val()));
        }
        let refs: Vec<&str> = inputs.iter().map(|s| s.as_str()).collect();
        let attrs = vec![
            attr_ints("kernel_shape", &conv.kernel_size.map(|k| k as i64)),
            attr_ints("strides", &conv.stride.map(|s| s as i64)),
            attr_ints("dilations", &conv.dilation.map(|d| d as i64)),
            attr_ints("pads", &pads),
            attr_int("group", conv.groups as i64),
        ];
        Ok(self.node("Conv", name, &refs, attrs))
    }

    fn batch_norm(&mut self, name: &str, bn: &BatchNorm, x: &str) -> String {
        let scale = self.weight(&format!("{name}.weight"), bn.gamma.val());
        let bias = self.weight(&format!("{name}.bias"), bn.beta.val());
        let mean = self.weight(&format!("{name}.running_mean"), bn.running_mean.value());
        let var = self.weight(&format!("{name}.running_var"), bn.running_var.value());
        self.node(
            "BatchNormalization",
            name,
            &[x, &scale, &bias, &mean, &var],
            vec![attr_float("epsilon", bn.epsilon as f32)],
        )
    }

    fn relu(&mut self, name: &str, x: &str) -> String {
        self.node("Relu", name, &[x], vec![])
    }

    fn norm_relu(&mut self, name: &str, bn: &BatchNorm, x: &str) -> String {
        let y = self.batch_norm(name, bn, x);
        self.relu(&format!("{name}.relu"), &y)
    }

    fn concat(&mut self, name: &str, parts: &[&str]) -> String {
        self.node("Concat", name, parts, vec![attr_int("axis", 1)])
    }

    fn dense_block(&mut self, name: &str, block: &DenseBlock, x: &str) -> Result<String, OnnxError> {
        let mut features = x.to_string();
        for (i, layer) in block.layers.iter().enumerate() {
            let p = format!("{name}.layers.{i}");
            let y = self.norm_relu(&format!("{p}.norm1"), &layer.norm1, &features);
            let y = self.conv(&format!("{p}.conv1"), &layer.conv1, &y)?;
            let y = match &layer.norm2 {
                Some(norm) => self.norm_relu(&format!("{p}.norm2"), norm, &y),
                None => self.relu(&format!("{p}.conv1.relu"), &y),
            };
            let y = self.conv(&format!("{p}.conv2"), &layer.conv2, &y)?;
            features = self.concat(&format!("{p}.concat"), &[&features, &y]);
        }
        Ok(features)
    }

    fn transition(&mut self, name: &str, t: &Transition, x: &str) -> Result<String, OnnxError> {
        let y = self.norm_relu(&format!("{name}.norm"), &t.norm, x);
        let attrs = vec![
            attr_ints("kernel_shape", &t.pool.kernel_size.map(|k| k as i64)),
            attr_ints("strides", &t.pool.stride.map(|s| s as i64)),
        ];
        let y = self.node("AveragePool", &format!("{name}.pool"), &[&y], attrs);
        self.conv(&format!("{name}.conv"), &t.conv, &y)
    }

    /// Bilinear resize of `x` to `skip`'s height and width (align_corners), concatenated
    /// before `skip`, then the block's two convolutions with LeakyReLU(0.2).
    fn up_block(&mut self, name: &str, block: &UpBlock, x: &str, skip: &str) -> Result<String, OnnxError> {
        let x_shape = self.node("Shape", &format!("{name}.x_shape"), &[x], vec![]);
        let skip_shape = self.node("Shape", &format!("{name}.skip_shape"), &[skip], vec![]);
        let [s0, s2, s4] = [0, 2, 4].map(|i| self.int64s(&format!("const.{i}"), &[i]));
        let nc = self.node("Slice", &format!("{name}.nc"), &[&x_shape, &s0, &s2], vec![]);
        let hw = self.node("Slice", &format!("{name}.hw"), &[&skip_shape, &s2, &s4], vec![]);
        let sizes = self.node("Concat", &format!("{name}.sizes"), &[&nc, &hw], vec![attr_int("axis", 0)]);
        let attrs = vec![attr_string("mode", "linear"), attr_string("coordinate_transformation_mode", "align_corners")];
        let up = self.node("Resize", &format!("{name}.resize"), &[x, "", "", &sizes], attrs);
        let y = self.concat(&format!("{name}.concat"), &[&up, skip]);
        let y = self.conv(&format!("{name}.conv_a"), &block.conv_a, &y)?;
        let y = self.node(
            "LeakyRelu",
            &format!("{name}.conv_a.leaky"),
            &[&y],
            vec![attr_float("alpha", LEAKY_SLOPE as f32)],
        );
        let y = self.conv(&format!("{name}.conv_b"), &block.conv_b, &y)?;
        Ok(self.node(
            "LeakyRelu",
            &format!("{name}.conv_b.leaky"),
            &[&y],
            vec![attr_float("alpha", LEAKY_SLOPE as f32)],
        ))
    }

    /// The force head (`crate::ForceHead`) on relu(norm5) and, where it has its skip, on
    /// relu(transition2): `[batch, 3]`, N.
    fn force_head(&mut self, head: &crate::ForceHead, features: &str, transition2: &str) -> Result<String, OnnxError> {
        let mut pooled = self.pooled_1x1("decoder.force.conv", &head.conv, features)?;
        if let Some(skip) = &head.skip {
            let t2 = self.relu("decoder.force.skip.relu", transition2);
            let more = self.pooled_1x1("decoder.force.skip", skip, &t2)?;
            pooled = self.node("Add", "decoder.force.pooled", &[&pooled, &more], vec![]);
        }
        // Burn's Linear holds [in, out]: x W + b.
        let w = self.weight("decoder.force.linear.weight", head.linear.weight.val());
        let y = self.node("MatMul", "decoder.force.linear", &[&pooled, &w], vec![]);
        let y = match &head.linear.bias {
            Some(b) => {
                let b = self.weight("decoder.force.linear.bias", b.val());
                self.node("Add", "decoder.force.linear.bias_add", &[&y, &b], vec![])
            }
            None => y,
        };
        let unit = self.scalar("decoder.force.n_per_unit", crate::FORCE_N_PER_LOSS_UNIT);
        Ok(self.node("Mul", "decoder.force.n", &[&y, &unit], vec![]))
    }

    /// One of `ForceHead`'s 1x1 convolutions, named by its module path as every weight here is,
    /// then LeakyReLU and the mean over the image: `[batch, C]`.
    fn pooled_1x1(&mut self, name: &str, conv: &Conv2d, x: &str) -> Result<String, OnnxError> {
        let y = self.conv(name, conv, x)?;
        let leaky = vec![attr_float("alpha", LEAKY_SLOPE as f32)];
        let y = self.node("LeakyRelu", &format!("{name}.leaky"), &[&y], leaky);
        // Opset 17's ReduceMean takes its axes as an attribute.
        let attrs = vec![attr_ints("axes", &[2, 3]), attr_int("keepdims", 0)];
        Ok(self.node("ReduceMean", &format!("{name}.mean"), &[&y], attrs))
    }

    /// The depth output's name, and the pressure's and the force head's where the network has them.
    fn densedepth(&mut self, net: &DenseDepth, input: &str) -> Result<NetOutputs, OnnxError> {
        let e = &net.encoder;
        let y = self.conv("encoder.conv0", &e.conv0, input)?;
        let relu0 = match &e.norm0 {
            Some(norm) => self.norm_relu("encoder.norm0", norm, &y),
            None => self.relu("encoder.relu0", &y),
        };
        let pads = match e.pool0.padding {
            PaddingConfig2d::Explicit(t, l, b, r) => [t, l, b, r].map(|p| p as i64),
            _ => [0, 0, 0, 0],
        };
        let pool_attrs = vec![
            attr_ints("kernel_shape", &e.pool0.kernel_size.map(|k| k as i64)),
            attr_ints("strides", &e.pool0.stride.map(|s| s as i64)),
            attr_ints("pads", &pads),
            attr_int("ceil_mode", i64::from(e.pool0.ceil_mode)),
        ];
        let pool0 = self.node("MaxPool", "encoder.pool0", &[&relu0], pool_attrs);
        let y = self.dense_block("encoder.denseblock1", &e.denseblock1, &pool0)?;
        let t1 = self.transition("encoder.transition1", &e.transition1, &y)?;
        let y = self.dense_block("encoder.denseblock2", &e.denseblock2, &t1)?;
        let t2 = self.transition("encoder.transition2", &e.transition2, &y)?;
        let y = self.dense_block("encoder.denseblock3", &e.denseblock3, &t2)?;
        let t3 = self.transition("encoder.transition3", &e.transition3, &y)?;
        let y = self.dense_block("encoder.denseblock4", &e.denseblock4, &t3)?;
        // The bottleneck reads relu(norm5).
        let norm5 = self.norm_relu("encoder.norm5", &e.norm5, &y);

        let d = &net.decoder;
        let force = match &d.force {
            Some(head) => Some(self.force_head(head, &norm5, &t2)?),
            None => None,
        };
        let x = self.conv("decoder.conv2", &d.conv2, &norm5)?;
        let x = self.up_block("decoder.up1", &d.up1, &x, &t2)?;
        let x = self.up_block("decoder.up2", &d.up2, &x, &t1)?;
        let x = self.up_block("decoder.up3", &d.up3, &x, &pool0)?;
        let x = self.up_block("decoder.up4", &d.up4, &x, &relu0)?;
        let x = match &d.up5 {
            Some(up5) => self.up_block("decoder.up5", up5, &x, input)?,
            None => x,
        };
        let pressure = match &d.pressure {
            Some(conv) => Some(self.conv("decoder.pressure", conv, &x)?),
            None => None,
        };
        Ok(NetOutputs { depth: self.conv("decoder.conv3", &d.conv3, &x)?, pressure, force })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    #[test]
    fn zero_valued_attributes_are_on_the_wire() {
        // `i` is field 3, a varint: key (3 << 3) | 0, then the value 0.
        let bytes = attr_int("ceil_mode", 0).encode_to_vec();
        assert!(bytes.windows(2).any(|w| w == [0x18, 0x00]), "{bytes:?}");
        // `f` is field 2, 32 bits: key (2 << 3) | 5, then four zero bytes.
        let bytes = attr_float("alpha", 0.0).encode_to_vec();
        assert!(bytes.windows(5).any(|w| w == [0x15, 0, 0, 0, 0]), "{bytes:?}");
        // And they read back as present.
        let back = AttributeProto::decode(attr_int("axis", 0).encode_to_vec().as_slice()).unwrap();
        assert_eq!(back.i, Some(0));
    }
}
