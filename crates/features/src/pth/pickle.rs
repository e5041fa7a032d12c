//! The subset of Python's pickle virtual machine that `torch.save` emits (protocols 2–5).
//!
//! Only data is rebuilt: no Python code runs. Globals are kept as names; the few callables a
//! state dict uses (`collections.OrderedDict`, `torch._utils._rebuild_tensor_v2`,
//! `torch._utils._rebuild_parameter`) are interpreted, every other call is kept as an opaque
//! [`Value::Call`] so an unusual checkpoint still loads as far as its tensors go.

use std::collections::HashMap;

/// A Python value as far as a checkpoint needs it.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Value>),
    List(Vec<Value>),
    /// Insertion-ordered, like the `OrderedDict` of a state dict.
    Dict(Vec<(Value, Value)>),
    /// `module.name`, as referenced by GLOBAL / STACK_GLOBAL.
    Global {
        module: String,
        name: String,
    },
    /// A persistent id (torch: a storage reference tuple).
    PersistentId(Box<Value>),
    /// A tensor view of a storage, from `_rebuild_tensor_v2`.
    Tensor(TensorView),
    /// Any other call `func(*args)`, kept uninterpreted.
    Call {
        func: Box<Value>,
        args: Box<Value>,
    },
}

/// Where a tensor's elements live: storage key, element type, and the view's geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct TensorView {
    pub storage_key: String,
    /// The storage class name, e.g. `FloatStorage`.
    pub storage_type: String,
    pub offset: usize,
    pub shape: Vec<usize>,
    pub stride: Vec<usize>,
}

/// A malformed or unsupported pickle stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PickleError(pub String);

type Res<T> = Result<T, PickleError>;

fn err<T>(message: impl Into<String>) -> Res<T> {
    Err(PickleError(message.into()))
}

/// Deepest nesting of values accepted (a state dict needs about ten): deeper values would
/// overflow the stack when they are dropped, compared or walked.
pub const MAX_DEPTH: u32 = 100;

/// Bytes the memo may copy in all, beyond [`COPY_BYTES_PER_INPUT_BYTE`] per input byte. Python
/// shares memoised objects; this reader copies them, so a few bytes of BINGET/BINPUT could
/// otherwise double a value at each step (a "billion laughs").
pub const COPY_BUDGET: usize = 64 << 20;
pub const COPY_BYTES_PER_INPUT_BYTE: usize = 1024;

/// A value on the stack or in the memo, with its nesting depth (1 for a leaf).
#[derive(Debug)]
enum Slot {
    Mark,
    Value(Value, u32),
}

/// Runs one pickle from `bytes`; returns the unpickled value and the number of bytes consumed.
pub fn unpickle(bytes: &[u8]) -> Res<(Value, usize)> {
    let mut machine = Machine {
        bytes,
        pos: 0,
        stack: Vec::new(),
        memo: HashMap::new(),
        copy_budget: bytes
            .len()
            .saturating_mul(COPY_BYTES_PER_INPUT_BYTE)
            .saturating_add(COPY_BUDGET),
    };
    let value = machine.run()?;
    Ok((value, machine.pos))
}

struct Machine<'a> {
    bytes: &'a [u8],
    pos: usize,
    stack: Vec<Slot>,
    memo: HashMap<u32, (Value, u32)>,
    /// Bytes the memo may still copy.
    copy_budget: usize,
}

/// Approximate heap size of `v` (bounded recursion: values are at most [`MAX_DEPTH`] deep).
fn weight(v: &Value) -> usize {
    let own = std::mem::size_of::<Value>();
    own + match v {
        Value::Str(s) => s.len(),
        Value::Bytes(b) => b.len(),
        Value::Tuple(items) | Value::List(items) => items.iter().map(weight).sum(),
        Value::Dict(items) => items.iter().map(|(k, v)| weight(k) + weight(v)).sum(),
        Value::Global { module, name } => module.len() + name.len(),
        Value::PersistentId(v) => weight(v),
        Value::Tensor(t) => {
            t.storage_key.len() + t.storage_type.len() + 8 * (t.shape.len() + t.stride.len())
        }
        Value::Call { func, args } => weight(func) + weight(args),
        Value::None | Value::Bool(_) | Value::Int(_) | Value::Float(_) => 0,
    }
}

/// The depth of a container holding a child of depth `child`, or an error past [`MAX_DEPTH`].
fn parent_depth(child: u32) -> Res<u32> {
    if child >= MAX_DEPTH {
        return err(format!("values nested deeper than {MAX_DEPTH}"));
    }
    Ok(child + 1)
}

impl Machine<'_> {
    fn take(&mut self, n: usize) -> Res<&[u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return err(format!("truncated at byte {}", self.pos));
        };
        let slice = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(slice)
    }

    fn u8(&mut self) -> Res<u8> {
        Ok(self.take(1)?[0])
    }

    fn u16(&mut self) -> Res<u16> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self) -> Res<u32> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn line(&mut self) -> Res<String> {
        let start = self.pos;
        let Some(len) = self.bytes[start..].iter().position(|&b| b == b'\n') else {
            return err("unterminated text line");
        };
        self.pos = start + len + 1;
        Ok(String::from_utf8_lossy(&self.bytes[start..start + len]).into_owned())
    }

    fn utf8(&mut self, n: usize) -> Res<Value> {
        let b = self.take(n)?;
        match std::str::from_utf8(b) {
            Ok(s) => Ok(Value::Str(s.to_owned())),
            Err(_) => err("invalid UTF-8 string"),
        }
    }

    /// Pushes a leaf value.
    fn push(&mut self, v: Value) {
        self.stack.push(Slot::Value(v, 1));
    }

    /// Pushes a container whose deepest child has depth `child`.
    fn push_parent(&mut self, v: Value, child: u32) -> Res<()> {
        let depth = parent_depth(child)?;
        self.stack.push(Slot::Value(v, depth));
        Ok(())
    }

    fn pop(&mut self) -> Res<Value> {
        Ok(self.pop_depth()?.0)
    }

    fn pop_depth(&mut self) -> Res<(Value, u32)> {
        match self.stack.pop() {
            Some(Slot::Value(v, d)) => Ok((v, d)),
            Some(Slot::Mark) => err("unexpected MARK on the stack"),
            None => err("stack underflow"),
        }
    }

    /// The value on top of the stack, which will hold children of depth up to `child`.
    fn top_mut(&mut self, child: u32) -> Res<&mut Value> {
        match self.stack.last_mut() {
            Some(Slot::Value(v, d)) => {
                *d = (*d).max(parent_depth(child)?);
                Ok(v)
            }
            _ => err("no value on top of the stack"),
        }
    }

    /// Pops everything down to the last MARK, with the deepest item's depth (0: none).
    fn pop_mark(&mut self) -> Res<(Vec<Value>, u32)> {
        let Some(mark) = self.stack.iter().rposition(|s| matches!(s, Slot::Mark)) else {
            return err("missing MARK");
        };
        let items = self.stack.split_off(mark + 1);
        self.stack.pop();
        let mut depth = 0;
        let items = items
            .into_iter()
            .map(|s| match s {
                Slot::Value(v, d) => {
                    depth = depth.max(d);
                    v
                }
                Slot::Mark => Value::None,
            })
            .collect();
        Ok((items, depth))
    }

    /// Charges a copy of `v` to the memo's budget.
    fn charge(&mut self, v: &Value) -> Res<()> {
        let w = weight(v);
        if w > self.copy_budget {
            return err("memoised values copied beyond the size budget (a pickle bomb?)");
        }
        self.copy_budget -= w;
        Ok(())
    }

    fn memo_put(&mut self, key: u32) -> Res<()> {
        let (v, d) = match self.stack.last() {
            Some(Slot::Value(v, d)) => (v, *d),
            _ => return err("memoize without a value"),
        };
        let v = v.clone();
        self.charge(&v)?;
        self.memo.insert(key, (v, d));
        Ok(())
    }

    fn memo_get(&mut self, key: u32) -> Res<()> {
        match self.memo.get(&key) {
            Some((v, d)) => {
                let (v, d) = (v.clone(), *d);
                self.charge(&v)?;
                self.stack.push(Slot::Value(v, d));
                Ok(())
            }
            None => err(format!("memo key {key} not found")),
        }
    }

    fn run(&mut self) -> Res<Value> {
        loop {
            let op = self.u8()?;
            match op {
                0x80 => {
                    self.u8()?; // PROTO
                }
                0x95 => {
                    self.take(8)?; // FRAME
                }
                b'.' => return self.pop(),
                b'(' => self.stack.push(Slot::Mark),
                b'}' => self.push(Value::Dict(Vec::new())),
                b']' => self.push(Value::List(Vec::new())),
                b')' => self.push(Value::Tuple(Vec::new())),
                b'N' => self.push(Value::None),
                0x88 => self.push(Value::Bool(true)),
                0x89 => self.push(Value::Bool(false)),
                b'K' => {
                    let v = self.u8()?;
                    self.push(Value::Int(v.into()));
                }
                b'M' => {
                    let v = self.u16()?;
                    self.push(Value::Int(v.into()));
                }
                b'J' => {
                    let v = self.u32()? as i32;
                    self.push(Value::Int(v.into()));
                }
                0x8a => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?;
                    if n > 8 {
                        // Wider than i64 (torch's legacy magic number): kept as raw bytes.
                        let raw = b.to_vec();
                        self.push(Value::Bytes(raw));
                        continue;
                    }
                    let mut buf = if b.last().is_some_and(|&x| x & 0x80 != 0) {
                        [0xff; 8]
                    } else {
                        [0; 8]
                    };
                    buf[..n].copy_from_slice(b);
                    self.push(Value::Int(i64::from_le_bytes(buf)));
                }
                b'G' => {
                    let b = self.take(8)?;
                    let v = f64::from_be_bytes(b.try_into().expect("8 bytes"));
                    self.push(Value::Float(v));
                }
                b'X' => {
                    let n = self.u32()? as usize;
                    let v = self.utf8(n)?;
                    self.push(v);
                }
                0x8c => {
                    let n = self.u8()? as usize;
                    let v = self.utf8(n)?;
                    self.push(v);
                }
                b'T' => {
                    let n = self.u32()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Str(String::from_utf8_lossy(&b).into_owned()));
                }
                b'U' => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Str(String::from_utf8_lossy(&b).into_owned()));
                }
                b'B' => {
                    let n = self.u32()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b));
                }
                b'C' => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b));
                }
                b'q' => {
                    let k = self.u8()?.into();
                    self.memo_put(k)?;
                }
                b'r' => {
                    let k = self.u32()?;
                    self.memo_put(k)?;
                }
                0x94 => {
                    let k = u32::try_from(self.memo.len()).unwrap_or(u32::MAX);
                    self.memo_put(k)?;
                }
                b'h' => {
                    let k = self.u8()?.into();
                    self.memo_get(k)?;
                }
                b'j' => {
                    let k = self.u32()?;
                    self.memo_get(k)?;
                }
                b't' => {
                    let (items, d) = self.pop_mark()?;
                    self.push_parent(Value::Tuple(items), d)?;
                }
                0x85..=0x87 => {
                    let n = (op - 0x84) as usize;
                    let mut items = Vec::with_capacity(n);
                    let mut depth = 0;
                    for _ in 0..n {
                        let (v, d) = self.pop_depth()?;
                        items.push(v);
                        depth = depth.max(d);
                    }
                    items.reverse();
                    self.push_parent(Value::Tuple(items), depth)?;
                }
                b'l' => {
                    let (items, d) = self.pop_mark()?;
                    self.push_parent(Value::List(items), d)?;
                }
                b'd' => {
                    let (items, d) = self.pop_mark()?;
                    let dict = pairs(items)?;
                    self.push_parent(Value::Dict(dict), d)?;
                }
                b'a' => {
                    let (v, d) = self.pop_depth()?;
                    match self.top_mut(d)? {
                        Value::List(l) => l.push(v),
                        _ => return err("APPEND to a non-list"),
                    }
                }
                b'e' => {
                    let (items, d) = self.pop_mark()?;
                    match self.top_mut(d)? {
                        Value::List(l) => l.extend(items),
                        _ => return err("APPENDS to a non-list"),
                    }
                }
                b's' => {
                    let (v, dv) = self.pop_depth()?;
                    let (k, dk) = self.pop_depth()?;
                    set_items(self.top_mut(dv.max(dk))?, vec![(k, v)])?;
                }
                b'u' => {
                    let (items, d) = self.pop_mark()?;
                    let items = pairs(items)?;
                    set_items(self.top_mut(d)?, items)?;
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    self.push(Value::Global { module, name });
                }
                0x93 => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    match (module, name) {
                        (Value::Str(module), Value::Str(name)) => {
                            self.push(Value::Global { module, name })
                        }
                        _ => return err("STACK_GLOBAL needs two strings"),
                    }
                }
                b'Q' => {
                    let (pid, d) = self.pop_depth()?;
                    self.push_parent(Value::PersistentId(Box::new(pid)), d)?;
                }
                b'R' | 0x81 => {
                    let (args, da) = self.pop_depth()?;
                    let (func, df) = self.pop_depth()?;
                    let v = call(func, args)?;
                    self.push_parent(v, da.max(df))?;
                }
                b'b' => {
                    // BUILD: object state (e.g. an OrderedDict's `_metadata`); data is kept as is.
                    self.pop()?;
                }
                _ => {
                    return err(format!(
                        "unsupported opcode 0x{op:02x} at byte {}",
                        self.pos - 1
                    ));
                }
            }
        }
    }
}

fn pairs(items: Vec<Value>) -> Res<Vec<(Value, Value)>> {
    if !items.len().is_multiple_of(2) {
        return err("odd number of dict items");
    }
    let mut out = Vec::with_capacity(items.len() / 2);
    let mut it = items.into_iter();
    while let (Some(k), Some(v)) = (it.next(), it.next()) {
        out.push((k, v));
    }
    Ok(out)
}

fn set_items(target: &mut Value, items: Vec<(Value, Value)>) -> Res<()> {
    match target {
        Value::Dict(d) => {
            for (k, v) in items {
                if let Some(slot) = d.iter_mut().find(|(key, _)| *key == k) {
                    slot.1 = v;
                } else {
                    d.push((k, v));
                }
            }
            Ok(())
        }
        _ => err("SETITEM(S) on a non-dict"),
    }
}

fn as_usizes(v: &Value) -> Res<Vec<usize>> {
    match v {
        Value::Tuple(items) | Value::List(items) => items
            .iter()
            .map(|x| match x {
                Value::Int(i) if *i >= 0 => Ok(*i as usize),
                _ => err("tensor size/stride entries must be non-negative integers"),
            })
            .collect(),
        _ => err("tensor size/stride must be a tuple"),
    }
}

/// Interprets the calls a state dict is made of; keeps the others as data.
fn call(func: Value, args: Value) -> Res<Value> {
    let Value::Global { module, name } = &func else {
        return Ok(Value::Call {
            func: Box::new(func),
            args: Box::new(args),
        });
    };
    let Value::Tuple(a) = &args else {
        return err(format!("{module}.{name}: arguments are not a tuple"));
    };
    match (module.as_str(), name.as_str()) {
        ("collections", "OrderedDict") | ("builtins", "dict") => Ok(Value::Dict(Vec::new())),
        ("torch._utils", "_rebuild_parameter") | ("torch._utils", "_rebuild_parameter_v2") => a
            .first()
            .cloned()
            .ok_or_else(|| PickleError("empty _rebuild_parameter".into())),
        ("torch._utils", "_rebuild_tensor_v2") | ("torch._utils", "_rebuild_tensor") => {
            let [storage, offset, size, stride, ..] = a.as_slice() else {
                return err("_rebuild_tensor_v2 with too few arguments");
            };
            let Value::PersistentId(pid) = storage else {
                return err("tensor storage is not a persistent id");
            };
            let Value::Tuple(pid) = pid.as_ref() else {
                return err("storage persistent id is not a tuple");
            };
            let (
                Some(Value::Global {
                    name: storage_type, ..
                }),
                Some(Value::Str(key)),
            ) = (pid.get(1), pid.get(2))
            else {
                return err("storage persistent id is not ('storage', type, key, ...)");
            };
            let Value::Int(offset) = offset else {
                return err("tensor storage offset is not an integer");
            };
            Ok(Value::Tensor(TensorView {
                storage_key: key.clone(),
                storage_type: storage_type.clone(),
                offset: usize::try_from(*offset)
                    .map_err(|_| PickleError("negative storage offset".into()))?,
                shape: as_usizes(size)?,
                stride: as_usizes(stride)?,
            }))
        }
        _ => Ok(Value::Call {
            func: Box::new(func),
            args: Box::new(args),
        }),
    }
}
