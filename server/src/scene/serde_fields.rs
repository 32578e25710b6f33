//! The field names a derived `Deserialize` struct reads, asked of the derive
//! itself so that no list of them is kept by hand.
//!
//! A derived struct hands its field names to
//! `Deserializer::deserialize_struct`; [`of`] calls it with a deserializer
//! that keeps them and stops there. serde has no other public way to list
//! them (its `FIELDS` constant is private to the derive).

use serde::de::{self, Deserialize, Deserializer, Visitor};

/// The names of the fields `T`'s derive reads (after renames).
///
/// # Panics
/// When `T` does not deserialize as a struct: a programming error, caught
/// by the first test that reads a scene.
pub fn of<'de, T: Deserialize<'de>>() -> &'static [&'static str] {
    let mut names = None;
    let _ = T::deserialize(FieldNames(&mut names));
    names.expect("a derived struct asks for its fields")
}

/// Keeps the field names it is asked for, and deserializes nothing.
struct FieldNames<'a>(&'a mut Option<&'static [&'static str]>);

impl<'de> Deserializer<'de> for FieldNames<'_> {
    type Error = de::value::Error;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
        Err(de::Error::custom("only reads a struct's field names"))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        fields: &'static [&'static str],
        _visitor: V,
    ) -> Result<V::Value, Self::Error> {
        *self.0 = Some(fields);
        Err(de::Error::custom("field names read"))
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf option unit unit_struct newtype_struct seq tuple
        tuple_struct map enum identifier ignored_any
    }
}

#[cfg(test)]
mod tests {
    use serde::Deserialize;

    /// The names are the derive's, renames applied, in declaration order.
    #[test]
    fn a_structs_field_names_are_read_from_its_derive() {
        #[derive(Deserialize)]
        #[allow(dead_code)]
        struct Probe {
            width_m: f64,
            #[serde(rename = "len_m")]
            length_m: f64,
            #[serde(default)]
            rim: bool,
        }
        assert_eq!(super::of::<Probe>(), ["width_m", "len_m", "rim"]);
    }
}
