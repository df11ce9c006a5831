//! A small XML reader for XMP packets: elements, attributes, text and namespaces, enough
//! for RDF properties written either as attributes or as child elements. No DTDs, no
//! external entities; nesting is bounded so that hostile input cannot exhaust memory.

const MAX_DEPTH: usize = 256;
const NS_XML: &str = "http://www.w3.org/XML/1998/namespace";

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Element {
    pub ns: String,
    pub local: String,
    qname: String,
    pub attrs: Vec<Attr>,
    pub children: Vec<Element>,
    pub text: String,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Attr {
    pub ns: String,
    pub local: String,
    pub value: String,
}

impl Element {
    /// An RDF property of this node: an attribute, or a child element's text, in any of
    /// the given namespaces.
    pub fn prop(&self, namespaces: &[&str], local: &str) -> Option<String> {
        let ns_ok = |ns: &str| namespaces.contains(&ns);
        if let Some(a) = self.attrs.iter().find(|a| a.local == local && ns_ok(&a.ns)) {
            return Some(a.value.clone());
        }
        self.children
            .iter()
            .find(|c| c.local == local && ns_ok(&c.ns) && !c.text.trim().is_empty())
            .map(|c| c.text.trim().to_owned())
    }

    /// The first property of that name on this node or any node below it.
    pub fn find_prop(&self, namespaces: &[&str], local: &str) -> Option<String> {
        self.find(&|e| e.prop(namespaces, local).is_some())
            .and_then(|e| e.prop(namespaces, local))
    }

    /// The first element, in document order, for which `pred` holds.
    pub fn find(&self, pred: &dyn Fn(&Element) -> bool) -> Option<&Element> {
        if pred(self) {
            return Some(self);
        }
        self.children.iter().find_map(|c| c.find(pred))
    }

    /// Calls `f` on this element and every element below it, in document order.
    pub fn visit(&self, f: &mut dyn FnMut(&Element)) {
        f(self);
        for c in &self.children {
            c.visit(f);
        }
    }
}

/// Parses an XML document into a synthetic root whose children are its top elements.
pub fn parse(bytes: &[u8]) -> Result<Element, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| format!("not UTF-8: {e}"))?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut parser = Parser {
        stack: vec![Element::default()],
        scopes: vec![vec![("xml".into(), NS_XML.into())]],
    };
    let mut rest = text;
    while !rest.is_empty() {
        let at = text.len() - rest.len();
        rest = parser
            .step(rest)
            .map_err(|e| format!("{e} (at byte {at})"))?;
    }
    if parser.stack.len() > 1 {
        let open = &parser.stack[parser.stack.len() - 1].qname;
        return Err(format!("element <{open}> is never closed"));
    }
    Ok(parser.stack.pop().expect("root"))
}

struct Parser {
    stack: Vec<Element>,
    /// Namespace declarations (prefix, URI) per open element; "" is the default namespace.
    scopes: Vec<Vec<(String, String)>>,
}

impl Parser {
    fn step<'a>(&mut self, rest: &'a str) -> Result<&'a str, String> {
        let Some(tag) = rest.strip_prefix('<') else {
            let end = rest.find('<').unwrap_or(rest.len());
            let text = decode_entities(&rest[..end])?;
            self.top().text.push_str(&text);
            return Ok(&rest[end..]);
        };
        if let Some(r) = tag.strip_prefix('?') {
            return after(r, "?>", "processing instruction");
        }
        if let Some(r) = tag.strip_prefix("!--") {
            return after(r, "-->", "comment");
        }
        if let Some(r) = tag.strip_prefix("![CDATA[") {
            let end = r.find("]]>").ok_or("unterminated CDATA section")?;
            self.top().text.push_str(&r[..end]);
            return Ok(&r[end + 3..]);
        }
        if let Some(r) = tag.strip_prefix('!') {
            return after(r, ">", "declaration");
        }
        if let Some(r) = tag.strip_prefix('/') {
            let end = r.find('>').ok_or("unterminated end tag")?;
            self.close(r[..end].trim())?;
            return Ok(&r[end + 1..]);
        }
        let end = tag_end(tag).ok_or("unterminated start tag")?;
        let (body, self_closing) = match tag[..end].strip_suffix('/') {
            Some(b) => (b, true),
            None => (&tag[..end], false),
        };
        self.open(body, self_closing)?;
        Ok(&tag[end + 1..])
    }

    fn top(&mut self) -> &mut Element {
        self.stack.last_mut().expect("root is never popped")
    }

    fn open(&mut self, body: &str, self_closing: bool) -> Result<(), String> {
        if self.stack.len() > MAX_DEPTH {
            return Err(format!("elements nested deeper than {MAX_DEPTH}"));
        }
        let (qname, attrs) = split_tag(body)?;
        let scope: Vec<(String, String)> = attrs
            .iter()
            .filter_map(|(k, v)| match k.as_str() {
                "xmlns" => Some((String::new(), v.clone())),
                _ => k.strip_prefix("xmlns:").map(|p| (p.to_owned(), v.clone())),
            })
            .collect();
        self.scopes.push(scope);
        let (ns, local) = self.resolve(&qname, true);
        let attrs = attrs
            .into_iter()
            .filter(|(k, _)| k != "xmlns" && !k.starts_with("xmlns:"))
            .map(|(k, value)| {
                let (ns, local) = self.resolve(&k, false);
                Attr { ns, local, value }
            })
            .collect();
        self.stack.push(Element {
            ns,
            local,
            qname,
            attrs,
            ..Element::default()
        });
        if self_closing {
            self.finish();
        }
        Ok(())
    }

    fn close(&mut self, qname: &str) -> Result<(), String> {
        if self.stack.len() < 2 {
            return Err(format!("end tag </{qname}> without a start tag"));
        }
        let open = &self.top().qname;
        if open != qname {
            return Err(format!("end tag </{qname}> does not match <{open}>"));
        }
        self.finish();
        Ok(())
    }

    fn finish(&mut self) {
        let done = self.stack.pop().expect("checked by caller");
        self.scopes.pop();
        self.top().children.push(done);
    }

    /// Namespace URI and local name; unprefixed attributes have no namespace, unknown
    /// prefixes resolve to none (such properties simply are not found).
    fn resolve(&self, qname: &str, element: bool) -> (String, String) {
        let (prefix, local) = match qname.split_once(':') {
            Some((p, l)) => (p, l),
            None if element => ("", qname),
            None => return (String::new(), qname.to_owned()),
        };
        let ns = self
            .scopes
            .iter()
            .rev()
            .flat_map(|s| s.iter().rev())
            .find(|(p, _)| p == prefix)
            .map(|(_, uri)| uri.clone())
            .unwrap_or_default();
        (ns, local.to_owned())
    }
}

fn after<'a>(rest: &'a str, end: &str, what: &str) -> Result<&'a str, String> {
    rest.find(end)
        .map(|i| &rest[i + end.len()..])
        .ok_or_else(|| format!("unterminated {what}"))
}

/// Index of the `>` ending a start tag, skipping quoted attribute values.
fn tag_end(tag: &str) -> Option<usize> {
    let mut quote = None;
    for (i, c) in tag.char_indices() {
        match (quote, c) {
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), _) if c == q => quote = None,
            (None, '>') => return Some(i),
            _ => {}
        }
    }
    None
}

type RawAttrs = Vec<(String, String)>;

fn split_tag(body: &str) -> Result<(String, RawAttrs), String> {
    let body = body.trim();
    let name_end = body.find(char::is_whitespace).unwrap_or(body.len());
    let name = &body[..name_end];
    if name.is_empty() {
        return Err("start tag without a name".into());
    }
    let mut rest = body[name_end..].trim_start();
    let mut attrs = Vec::new();
    while !rest.is_empty() {
        let eq = rest
            .find('=')
            .ok_or_else(|| format!("attribute without a value in <{name}>"))?;
        let key = rest[..eq].trim();
        let value = rest[eq + 1..].trim_start();
        let quote = value
            .chars()
            .next()
            .filter(|c| *c == '"' || *c == '\'')
            .ok_or_else(|| format!("unquoted value of {key} in <{name}>"))?;
        let close = value[1..]
            .find(quote)
            .ok_or_else(|| format!("unterminated value of {key} in <{name}>"))?;
        attrs.push((key.to_owned(), decode_entities(&value[1..1 + close])?));
        rest = value[close + 2..].trim_start();
    }
    Ok((name.to_owned(), attrs))
}

fn decode_entities(s: &str) -> Result<String, String> {
    if !s.contains('&') {
        return Ok(s.to_owned());
    }
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find('&') {
        out.push_str(&rest[..i]);
        let end = rest[i..].find(';').ok_or("'&' without a terminating ';'")?;
        let name = &rest[i + 1..i + end];
        let c = match name {
            "lt" => '<',
            "gt" => '>',
            "amp" => '&',
            "quot" => '"',
            "apos" => '\'',
            _ => {
                let code = match name.strip_prefix("#x").or_else(|| name.strip_prefix("#X")) {
                    Some(hex) => u32::from_str_radix(hex, 16).ok(),
                    None => name.strip_prefix('#').and_then(|d| d.parse().ok()),
                };
                code.and_then(char::from_u32)
                    .ok_or_else(|| format!("unknown entity &{name};"))?
            }
        };
        out.push(c);
        rest = &rest[i + end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DOC: &str = r#"<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
<rdf:Description xmlns:a="urn:a" a:One="1 &amp; 2" a:Quote='say "hi"'>
  <a:Two>two&#x21;</a:Two><!-- a > comment --><a:Empty/>
</rdf:Description></rdf:RDF></x:xmpmeta><?xpacket end="w"?>"#;

    #[test]
    fn properties_as_attributes_and_elements() {
        let root = parse(DOC.as_bytes()).unwrap();
        assert_eq!(root.find_prop(&["urn:a"], "One").as_deref(), Some("1 & 2"));
        assert_eq!(
            root.find_prop(&["urn:a"], "Quote").as_deref(),
            Some("say \"hi\"")
        );
        assert_eq!(root.find_prop(&["urn:a"], "Two").as_deref(), Some("two!"));
        assert_eq!(root.find_prop(&["urn:b"], "One"), None);
        assert_eq!(root.find_prop(&["urn:a"], "Empty"), None);
    }

    #[test]
    fn malformed_documents_are_errors() {
        for (doc, needle) in [
            ("<a><b></a>", "does not match"),
            ("<a>", "never closed"),
            ("<a x=1/>", "unquoted"),
            ("<a x='1/>", "unterminated"),
            ("<a>&bogus;</a>", "unknown entity"),
            ("</a>", "without a start tag"),
            ("<!-- open", "unterminated comment"),
        ] {
            let err = parse(doc.as_bytes()).unwrap_err();
            assert!(err.contains(needle), "{doc}: {err}");
        }
        assert!(parse(&[0x3c, 0xff, 0x3e]).unwrap_err().contains("UTF-8"));
        let deep = "<a>".repeat(MAX_DEPTH + 2);
        assert!(parse(deep.as_bytes()).unwrap_err().contains("deeper"));
    }
}
