//! Reading and writing [`Mlp`]s as safetensors files.
//!
//! The layout is PyTorch's `state_dict` of an `nn.Sequential(Linear, ReLU, Linear, …)`:
//! tensors `0.weight` `[out, in]`, `0.bias` `[out]`, `2.weight`, `2.bias`, … (a ReLU sits at
//! every odd index). Loading is liberal in names and strict in shapes:
//!
//! - any common prefix is accepted (`net.0.weight`, `model.layers.3.bias`), and any strictly
//!   increasing integer indices; layers are taken in index order;
//! - so are layers named with a number (`fc1.weight`, `fc2.weight`, …, `fc10.weight`, a
//!   module's `self.fc1 = nn.Linear(…)` with ReLU between), in the order of their numbers;
//! - every index needs both `.weight` and `.bias`; weights must be 2-D `[out, in]`, biases
//!   `[out]`, and each layer's `in` must equal the previous layer's `out`;
//! - dtypes F32 and F64 are accepted (F32 is widened exactly to f64); NaN and ±∞ are rejected;
//! - metadata is optional; if `activation` is present it must be `relu`, and if `architecture`
//!   is present it must match the tensors.
//!
//! Saving writes F64 (trained weights stay bit-exact) under the names `0, 2, 4, …`, so the file
//! loads into PyTorch with `nn.Sequential(...).load_state_dict(safetensors.torch.load_file(p))`
//! (after `.double()`), and metadata
//! `{"format": "cbfreach-mlp", "architecture": "2x400x400x400x2", "activation": "relu", …}`.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use super::{Layer, Mlp, NetworkError};

/// Value of the `format` metadata key in files this crate writes.
pub const FORMAT_NAME: &str = "cbfreach-mlp";

/// Metadata keys this crate sets itself; extras with these names are overwritten.
pub const RESERVED_METADATA_KEYS: [&str; 3] = ["format", "architecture", "activation"];

impl Mlp {
    /// Loads a network from a safetensors file (see the [module docs](self) for the layout).
    pub fn load_safetensors(path: &Path) -> Result<Mlp, NetworkError> {
        Self::load_safetensors_with_metadata(path).map(|(mlp, _)| mlp)
    }

    /// Loads a network and the file's string metadata (training statistics and the like).
    pub fn load_safetensors_with_metadata(
        path: &Path,
    ) -> Result<(Mlp, BTreeMap<String, String>), NetworkError> {
        let bytes = std::fs::read(path).map_err(|source| NetworkError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        parse(&bytes, path)
    }

    /// Parses a network from safetensors bytes; `name_for_errors` stands in for the path in
    /// error messages.
    pub fn from_safetensors_bytes(
        bytes: &[u8],
        name_for_errors: &str,
    ) -> Result<Mlp, NetworkError> {
        parse(bytes, Path::new(name_for_errors)).map(|(mlp, _)| mlp)
    }

    /// Serialises the network to safetensors bytes (F64, PyTorch `nn.Sequential` names).
    /// `extra_metadata` is stored beside the standard keys ([`RESERVED_METADATA_KEYS`] win).
    pub fn to_safetensors_bytes(
        &self,
        extra_metadata: &BTreeMap<String, String>,
    ) -> Result<Vec<u8>, NetworkError> {
        self.serialize_as(Dtype::F64, extra_metadata)
    }

    /// Writes the network to `path` (F64, PyTorch `nn.Sequential` names, see the
    /// [module docs](self)). The file is written beside `path` and renamed into place, so a
    /// crash never leaves a half-written network.
    pub fn save_safetensors(
        &self,
        path: &Path,
        extra_metadata: &BTreeMap<String, String>,
    ) -> Result<(), NetworkError> {
        let bytes = self.to_safetensors_bytes(extra_metadata)?;
        write_atomically(path, &bytes)
    }
}

impl Mlp {
    /// As [`Mlp::save_safetensors`], with F32 tensors (half the size). Refuses
    /// ([`NetworkError::Settings`]) a network whose weights are not all exactly representable
    /// in f32, so the saved network is the same function (e.g. any network from the f32
    /// trainer).
    pub fn save_safetensors_f32(
        &self,
        path: &Path,
        extra_metadata: &BTreeMap<String, String>,
    ) -> Result<(), NetworkError> {
        self.validate("<network being saved>")?;
        let exact = |v: &[f64]| v.iter().all(|&x| (x as f32) as f64 == x);
        if !self
            .layers
            .iter()
            .all(|l| exact(&l.weight) && exact(&l.bias))
        {
            return Err(NetworkError::Settings {
                message: "the weights are not exactly representable in f32: save as F64".into(),
            });
        }
        let bytes = self.serialize_as(Dtype::F32, extra_metadata)?;
        write_atomically(path, &bytes)
    }

    /// The network as safetensors bytes with `dtype` tensors (F64, or F32 when the caller has
    /// checked that the weights are exactly representable) under PyTorch `nn.Sequential`
    /// names, and the standard metadata keys over `extra_metadata`.
    fn serialize_as(
        &self,
        dtype: Dtype,
        extra_metadata: &BTreeMap<String, String>,
    ) -> Result<Vec<u8>, NetworkError> {
        self.validate("<network being saved>")?;
        let bytes = |v: &[f64]| match dtype {
            Dtype::F32 => f32_bytes(&v.iter().map(|&x| x as f32).collect::<Vec<f32>>()),
            _ => f64_bytes(v),
        };
        let mut tensors: Vec<RawTensor> = Vec::new();
        for (k, l) in self.layers.iter().enumerate() {
            tensors.push((
                format!("{}.weight", 2 * k),
                dtype,
                vec![l.n_out, l.n_in],
                bytes(&l.weight),
            ));
            tensors.push((
                format!("{}.bias", 2 * k),
                dtype,
                vec![l.n_out],
                bytes(&l.bias),
            ));
        }
        let mut meta: HashMap<String, String> = extra_metadata
            .iter()
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        meta.insert("format".into(), FORMAT_NAME.into());
        meta.insert("architecture".into(), self.architecture());
        meta.insert("activation".into(), "relu".into());
        serialize(&tensors, meta, Path::new("<network being saved>"))
    }
}

/// Writes `bytes` to `path.tmp` and renames it to `path`.
pub(crate) fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), NetworkError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let io = |source| NetworkError::Io {
        path: path.to_path_buf(),
        source,
    };
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

/// Little-endian bytes of an f64 slice.
pub(crate) fn f64_bytes(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Little-endian bytes of an f32 slice.
pub(crate) fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A tensor to write: name, dtype, shape, little-endian bytes.
pub(crate) type RawTensor = (String, Dtype, Vec<usize>, Vec<u8>);

/// Serialises tensors and string metadata to safetensors bytes.
pub(crate) fn serialize(
    tensors: &[RawTensor],
    metadata: HashMap<String, String>,
    path: &Path,
) -> Result<Vec<u8>, NetworkError> {
    let format = |e: safetensors::SafeTensorError| NetworkError::Format {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let views = tensors
        .iter()
        .map(|(name, dtype, shape, data)| {
            TensorView::new(*dtype, shape.clone(), data).map(|v| (name.as_str(), v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(format)?;
    safetensors::tensor::serialize(views, Some(metadata)).map_err(format)
}

/// A parsed safetensors file: the tensors (as f64, with shapes) and the metadata.
pub(crate) struct RawTensors<'a> {
    st: SafeTensors<'a>,
    pub(crate) metadata: BTreeMap<String, String>,
    path: PathBuf,
}

impl<'a> RawTensors<'a> {
    /// Parses the header; fails with [`NetworkError::Format`] on anything not safetensors.
    pub(crate) fn parse(bytes: &'a [u8], path: &Path) -> Result<Self, NetworkError> {
        let format = |message: String| NetworkError::Format {
            path: path.to_path_buf(),
            message,
        };
        let (_, meta) = SafeTensors::read_metadata(bytes).map_err(|e| format(e.to_string()))?;
        let st = SafeTensors::deserialize(bytes).map_err(|e| format(e.to_string()))?;
        let metadata = meta
            .metadata()
            .as_ref()
            .map(|m| m.iter().map(|(k, v)| (k.clone(), v.clone())).collect())
            .unwrap_or_default();
        Ok(RawTensors {
            st,
            metadata,
            path: path.to_path_buf(),
        })
    }

    /// Tensor names in the file.
    pub(crate) fn names(&self) -> Vec<String> {
        self.st.names().into_iter().map(String::from).collect()
    }

    /// Shape of tensor `name`.
    pub(crate) fn shape(&self, name: &str) -> Result<Vec<usize>, NetworkError> {
        self.view(name).map(|v| v.shape().to_vec())
    }

    fn view(&self, name: &str) -> Result<TensorView<'a>, NetworkError> {
        self.st
            .tensor(name)
            .map_err(|_| NetworkError::MissingTensor {
                path: self.path.clone(),
                name: name.to_string(),
            })
    }

    /// Tensor `name` as f64 (F32 widened exactly), checked finite.
    pub(crate) fn f64s(&self, name: &str) -> Result<Vec<f64>, NetworkError> {
        let values = self.f64s_unchecked(name)?;
        if let Some(index) = values.iter().position(|x| !x.is_finite()) {
            return Err(NetworkError::NonFinite {
                path: self.path.clone(),
                name: name.to_string(),
                index,
            });
        }
        Ok(values)
    }

    /// Tensor `name` as f64 (F32 widened exactly), NaN and ∞ allowed.
    pub(crate) fn f64s_unchecked(&self, name: &str) -> Result<Vec<f64>, NetworkError> {
        let v = self.view(name)?;
        let data = v.data();
        let values: Vec<f64> = match v.dtype() {
            Dtype::F64 => data
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
                .collect(),
            Dtype::F32 => data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap_or([0; 4])) as f64)
                .collect(),
            other => {
                return Err(NetworkError::UnsupportedDtype {
                    path: self.path.clone(),
                    name: name.to_string(),
                    dtype: format!("{other:?}"),
                })
            }
        };
        Ok(values)
    }

    /// Tensor `name` as f32; only F32 tensors are accepted (used for checkpoints).
    pub(crate) fn f32s(&self, name: &str) -> Result<Vec<f32>, NetworkError> {
        let v = self.view(name)?;
        if v.dtype() != Dtype::F32 {
            return Err(NetworkError::UnsupportedDtype {
                path: self.path.clone(),
                name: name.to_string(),
                dtype: format!("{:?} (this checkpoint tensor must be F32)", v.dtype()),
            });
        }
        Ok(v.data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap_or([0; 4])))
            .collect())
    }
}

/// Splits `prefix.<index>.weight|bias`, or `prefix<index>.weight|bias` (a layer named with a
/// number, `fc1`), into `(prefix, index, is_weight)`.
fn split_key(key: &str) -> Option<(&str, u64, bool)> {
    let (rest, is_weight) = if let Some(r) = key.strip_suffix(".weight") {
        (r, true)
    } else if let Some(r) = key.strip_suffix(".bias") {
        (r, false)
    } else {
        return None;
    };
    let (prefix, idx) = match rest.rfind('.') {
        Some(p) => (&rest[..=p], &rest[p + 1..]),
        None => ("", rest),
    };
    if let Ok(index) = idx.parse::<u64>() {
        return Some((prefix, index, is_weight));
    }
    let name = idx.trim_end_matches(|c: char| c.is_ascii_digit());
    let split = rest.len() - (idx.len() - name.len());
    match name.is_empty() || name.len() == idx.len() {
        true => None,
        false => Some((&rest[..split], rest[split..].parse().ok()?, is_weight)),
    }
}

/// Parses an MLP from safetensors bytes (see the module docs for the accepted layout).
fn parse(bytes: &[u8], path: &Path) -> Result<(Mlp, BTreeMap<String, String>), NetworkError> {
    let raw = RawTensors::parse(bytes, path)?;
    let unsupported = |message: String| NetworkError::UnsupportedLayer {
        path: path.to_path_buf(),
        message,
    };
    if let Some(act) = raw.metadata.get("activation") {
        if !act.eq_ignore_ascii_case("relu") {
            return Err(unsupported(format!(
                "metadata says activation `{act}`, only `relu` is supported"
            )));
        }
    }
    let names = raw.names();
    if names.is_empty() {
        return Err(NetworkError::Empty);
    }
    // index -> (weight name, bias name)
    let mut layers: BTreeMap<u64, (Option<String>, Option<String>)> = BTreeMap::new();
    let mut prefix: Option<&str> = None;
    for name in &names {
        let Some((p, index, is_weight)) = split_key(name) else {
            return Err(unsupported(format!(
                "tensor `{name}` is not `<index>.weight` or `<index>.bias` of a Linear layer \
                 (nor `<name><index>.weight`, as `fc1.weight`)"
            )));
        };
        match prefix {
            None => prefix = Some(p),
            Some(q) if q != p => {
                return Err(unsupported(format!(
                    "tensor names have different prefixes (`{q}` and `{p}`): one nn.Sequential \
                     expected"
                )))
            }
            Some(_) => {}
        }
        let entry = layers.entry(index).or_default();
        if is_weight {
            entry.0 = Some(name.clone());
        } else {
            entry.1 = Some(name.clone());
        }
    }
    let prefix = prefix.unwrap_or("");
    let mut out = Vec::with_capacity(layers.len());
    let mut prev_out: Option<usize> = None;
    for (index, (w, b)) in &layers {
        let missing = |kind: &str| NetworkError::MissingTensor {
            path: path.to_path_buf(),
            name: format!("{prefix}{index}.{kind}"),
        };
        let w = w.as_ref().ok_or_else(|| missing("weight"))?;
        let b = b.as_ref().ok_or_else(|| missing("bias"))?;
        let w_shape = raw.shape(w)?;
        let b_shape = raw.shape(b)?;
        if b_shape.len() != 1 {
            return Err(NetworkError::Shape {
                path: path.to_path_buf(),
                name: b.clone(),
                expected: vec![w_shape.first().copied().unwrap_or(0)],
                found: b_shape,
            });
        }
        if w_shape.len() == 2 && w_shape[0] != b_shape[0] {
            return Err(NetworkError::Shape {
                path: path.to_path_buf(),
                name: b.clone(),
                expected: vec![w_shape[0]],
                found: b_shape,
            });
        }
        let n_out = b_shape[0];
        let n_in = prev_out.unwrap_or_else(|| w_shape.last().copied().unwrap_or(0));
        if w_shape != [n_out, n_in] || n_out == 0 || n_in == 0 {
            return Err(NetworkError::Shape {
                path: path.to_path_buf(),
                name: w.clone(),
                expected: vec![n_out.max(1), n_in.max(1)],
                found: w_shape,
            });
        }
        let weight = raw.f64s(w)?;
        let bias = raw.f64s(b)?;
        out.push(Layer {
            weight,
            bias,
            n_in,
            n_out,
        });
        prev_out = Some(n_out);
    }
    let mlp = Mlp { layers: out };
    if let Some(arch) = raw.metadata.get("architecture") {
        if *arch != mlp.architecture() {
            return Err(NetworkError::Format {
                path: path.to_path_buf(),
                message: format!(
                    "metadata architecture `{arch}` does not match the tensors ({})",
                    mlp.architecture()
                ),
            });
        }
    }
    Ok((mlp, raw.metadata))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes a PyTorch-style file of the given f32 tensors.
    fn torch_style(tensors: &[(&str, Vec<usize>, Vec<f32>)], dtype: Dtype) -> Vec<u8> {
        let t: Vec<RawTensor> = tensors
            .iter()
            .map(|(n, s, d)| {
                let bytes = match dtype {
                    Dtype::F32 => f32_bytes(d),
                    // f16 stand-in: 2 bytes per element
                    _ => vec![0u8; d.len() * dtype.bitsize() / 8],
                };
                (n.to_string(), dtype, s.clone(), bytes)
            })
            .collect();
        serialize(&t, HashMap::new(), Path::new("t")).unwrap()
    }

    fn small() -> Vec<(&'static str, Vec<usize>, Vec<f32>)> {
        vec![
            (
                "0.weight",
                vec![3, 2],
                vec![0.5, -1.0, 0.25, 2.0, -0.75, 1.5],
            ),
            ("0.bias", vec![3], vec![0.1, -0.2, 0.3]),
            ("2.weight", vec![1, 3], vec![1.0, -2.0, 0.5]),
            ("2.bias", vec![1], vec![0.125]),
        ]
    }

    #[test]
    fn round_trip_is_exact_and_keeps_metadata() {
        let mlp = Mlp::random(&[2, 7, 5, 3], 11);
        let mut extra = BTreeMap::new();
        extra.insert("max_error".to_string(), "0.19".to_string());
        extra.insert("format".to_string(), "overridden".to_string());
        // Removed on drop, also when an assertion panics.
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rt.safetensors");
        mlp.save_safetensors(&p, &extra).unwrap();
        let (back, meta) = Mlp::load_safetensors_with_metadata(&p).unwrap();
        assert_eq!(back, mlp);
        assert_eq!(meta["max_error"], "0.19");
        assert_eq!(meta["format"], FORMAT_NAME);
        assert_eq!(meta["architecture"], "2x7x5x3");
        assert_eq!(meta["activation"], "relu");
    }

    #[test]
    fn pytorch_f32_file_loads_and_evaluates_equal() {
        let bytes = torch_style(&small(), Dtype::F32);
        let mlp = Mlp::from_safetensors_bytes(&bytes, "torch.safetensors").unwrap();
        assert_eq!(mlp.widths(), vec![2, 3, 1]);
        let x = [0.3, -0.7];
        // by hand in f64 from the f32 values (all exactly representable)
        let h = [
            (0.5 * 0.3 - 1.0 * -0.7 + 0.1f32 as f64).max(0.0),
            (0.25 * 0.3 + 2.0 * -0.7 - 0.2f32 as f64).max(0.0),
            (-0.75 * 0.3 + 1.5 * -0.7 + 0.3f32 as f64).max(0.0),
        ];
        let y = 1.0 * h[0] - 2.0 * h[1] + 0.5 * h[2] + 0.125;
        assert!((mlp.forward(&x)[0] - y).abs() < 1e-15);
    }

    #[test]
    fn prefixed_and_sparse_indices_load() {
        let mut t = small();
        t[0].0 = "net.1.weight";
        t[1].0 = "net.1.bias";
        t[2].0 = "net.7.weight";
        t[3].0 = "net.7.bias";
        let mlp = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "p").unwrap();
        assert_eq!(mlp.widths(), vec![2, 3, 1]);
    }

    /// A module's `fc1`, `fc2`, … `fc10`: taken in the order of their numbers (`fc10` after
    /// `fc2`, which a text sort would not give; the shapes chain only in that order).
    #[test]
    fn layers_named_with_numbers_load_in_their_order() {
        let widths = [2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 1];
        let mut t: Vec<(String, Vec<usize>, Vec<f32>)> = Vec::new();
        for k in 0..widths.len() - 1 {
            let (i, o) = (widths[k], widths[k + 1]);
            t.push((
                format!("net.fc{}.weight", k + 1),
                vec![o, i],
                vec![0.5; o * i],
            ));
            t.push((format!("net.fc{}.bias", k + 1), vec![o], vec![0.0; o]));
        }
        let named: Vec<(&str, Vec<usize>, Vec<f32>)> = t
            .iter()
            .map(|(n, s, d)| (n.as_str(), s.clone(), d.clone()))
            .collect();
        let mlp = Mlp::from_safetensors_bytes(&torch_style(&named, Dtype::F32), "fc").unwrap();
        assert_eq!(mlp.widths(), widths.to_vec());
        // A name with no number is still refused, the message naming both forms.
        let mut t = small();
        t[0].0 = "out.weight";
        let err = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "o").unwrap_err();
        assert!(err.to_string().contains("`fc1.weight`"), "{err}");
    }

    #[test]
    fn shape_chain_mismatch_is_reported() {
        let mut t = small();
        t[2] = ("2.weight", vec![1, 4], vec![1.0, -2.0, 0.5, 0.0]);
        let err = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "chain").unwrap_err();
        match err {
            NetworkError::Shape {
                name,
                expected,
                found,
                ..
            } => {
                assert_eq!(name, "2.weight");
                assert_eq!(expected, vec![1, 3]);
                assert_eq!(found, vec![1, 4]);
            }
            e => panic!("wrong error {e}"),
        }
        // bias length must be `out`
        let mut t = small();
        t[1] = ("0.bias", vec![2], vec![0.0, 0.0]);
        let err = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "b").unwrap_err();
        assert!(
            matches!(err, NetworkError::Shape { ref name, ref expected, .. }
                if name == "0.bias" && *expected == vec![3]),
            "{err}"
        );
    }

    #[test]
    fn nan_weight_is_reported() {
        let mut t = small();
        t[2].2[1] = f32::NAN;
        let err = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "nan").unwrap_err();
        assert!(
            matches!(err, NetworkError::NonFinite { ref name, index: 1, .. } if name == "2.weight"),
            "{err}"
        );
    }

    #[test]
    fn f16_is_unsupported_dtype() {
        let err =
            Mlp::from_safetensors_bytes(&torch_style(&small(), Dtype::F16), "half").unwrap_err();
        assert!(
            matches!(err, NetworkError::UnsupportedDtype { ref dtype, .. } if dtype == "F16"),
            "{err}"
        );
        assert!(err.to_string().contains("half"));
    }

    #[test]
    fn missing_bias_is_reported() {
        let mut t = small();
        t.remove(3);
        let err = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "nobias").unwrap_err();
        assert!(
            matches!(err, NetworkError::MissingTensor { ref name, .. } if name == "2.bias"),
            "{err}"
        );
    }

    #[test]
    fn garbage_and_missing_files_are_reported() {
        let err =
            Mlp::from_safetensors_bytes(b"this is not a safetensors file", "junk").unwrap_err();
        assert!(matches!(err, NetworkError::Format { .. }), "{err}");
        let err = Mlp::from_safetensors_bytes(&[], "empty").unwrap_err();
        assert!(matches!(err, NetworkError::Format { .. }), "{err}");
        let err = Mlp::load_safetensors(Path::new("/nonexistent/net.safetensors")).unwrap_err();
        assert!(matches!(err, NetworkError::Io { .. }), "{err}");
        assert!(err.to_string().contains("/nonexistent/net.safetensors"));
    }

    #[test]
    fn other_layers_and_activations_are_unsupported() {
        let mut t = small();
        t.push(("1.running_mean", vec![3], vec![0.0; 3]));
        let err = Mlp::from_safetensors_bytes(&torch_style(&t, Dtype::F32), "bn").unwrap_err();
        assert!(
            matches!(err, NetworkError::UnsupportedLayer { .. }),
            "{err}"
        );

        let mlp = Mlp::random(&[2, 3, 1], 0);
        let bytes = mlp.to_safetensors_bytes(&BTreeMap::new()).unwrap();
        let raw = RawTensors::parse(&bytes, Path::new("x")).unwrap();
        let t: Vec<RawTensor> = raw
            .names()
            .into_iter()
            .map(|n| {
                let s = raw.shape(&n).unwrap();
                let d = f64_bytes(&raw.f64s(&n).unwrap());
                (n, Dtype::F64, s, d)
            })
            .collect();
        let mut meta = HashMap::new();
        meta.insert("activation".to_string(), "tanh".to_string());
        let bytes = serialize(&t, meta, Path::new("x")).unwrap();
        let err = Mlp::from_safetensors_bytes(&bytes, "tanh").unwrap_err();
        assert!(
            matches!(err, NetworkError::UnsupportedLayer { .. }),
            "{err}"
        );
    }

    #[test]
    fn file_without_tensors_is_empty() {
        let header = br#"{"__metadata__":{"format":"cbfreach-mlp"}}"#;
        let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
        bytes.extend_from_slice(header);
        let err = Mlp::from_safetensors_bytes(&bytes, "e").unwrap_err();
        assert!(matches!(err, NetworkError::Empty), "{err}");
    }
}
