"""Manual check (not run in CI; no controller there): a line-by-line transliteration of the
arithmetic of shaBlock, w32Xor/w32And/w32Rotr, wordsBytes, hmac50, authInit, hexBytes, bytesHex
and numBytes in cellcal/ (Python floats are doubles like VAL3's num; the bit operations are
asserted to see 16-bit operands only), compared with hashlib/hmac on random keys and with the
golden proofs of robotlink's auth.rs. Run: python3 val3_arithmetic_check.py. It checks the
algorithm as written, not the VAL3 interpreter: keep it in step with the .pgx files by hand."""
import hashlib, hmac, math, os
from decimal import Decimal, getcontext
rd=math.floor
nPow2=[1.0]
for i in range(1,33): nPow2.append(nPow2[-1]*2)
def bXor(a,b): assert a==int(a) and b==int(b) and 0<=a<65536 and 0<=b<65536; return float(int(a)^int(b))
def bAnd(a,b): assert a==int(a) and b==int(b) and 0<=a<65536 and 0<=b<65536; return float(int(a)&int(b))
def w32Xor(a,b):
    ah=rd(a/65536); bh=rd(b/65536); return bXor(ah,bh)*65536+bXor(a-ah*65536,b-bh*65536)
def w32And(a,b):
    ah=rd(a/65536); bh=rd(b/65536); return bAnd(ah,bh)*65536+bAnd(a-ah*65536,b-bh*65536)
def w32Rotr(a,n):
    hi=rd(a/nPow2[n]); return hi+(a-hi*nPow2[n])*nPow2[32-n]
getcontext().prec = 60
def primes(n):
    p, i = [], 2
    while len(p) < n:
        if all(i % q for q in p):
            p.append(i)
        i += 1
    return p
K = [float(int((Decimal(p) ** (Decimal(1) / Decimal(3)) % 1) * 2**32)) for p in primes(64)]
H0 = [float(int((Decimal(p).sqrt() % 1) * 2**32)) for p in primes(8)]
def shaBlock(H,B):
    W=[0.0]*64
    for i in range(16): W[i]=B[4*i]*16777216+B[4*i+1]*65536+B[4*i+2]*256+B[4*i+3]
    for i in range(16,64):
        n1=w32Rotr(W[i-15],7); n2=w32Rotr(W[i-15],18); n3=w32Xor(n1,n2); S0=w32Xor(n3,rd(W[i-15]/8))
        n1=w32Rotr(W[i-2],17); n2=w32Rotr(W[i-2],19); n3=w32Xor(n1,n2); S1=w32Xor(n3,rd(W[i-2]/1024))
        n1=W[i-16]+S0+W[i-7]+S1; W[i]=n1-rd(n1/4294967296)*4294967296
    V=list(H)
    for i in range(64):
        n1=w32Rotr(V[4],6); n2=w32Rotr(V[4],11); n3=w32Xor(n1,n2); n1=w32Rotr(V[4],25); S1=w32Xor(n3,n1)
        n1=w32Xor(V[5],V[6]); n2=w32And(V[4],n1); Ch=w32Xor(V[6],n2)
        T1=V[7]+S1+Ch+K[i]+W[i]
        n1=w32Rotr(V[0],2); n2=w32Rotr(V[0],13); n3=w32Xor(n1,n2); n1=w32Rotr(V[0],22); S0=w32Xor(n3,n1)
        n1=w32Xor(V[0],V[1]); n2=w32And(V[2],n1); n3=w32And(V[0],V[1]); Maj=w32Xor(n3,n2)
        T2=S0+Maj
        V[7]=V[6]; V[6]=V[5]; V[5]=V[4]; n1=V[3]+T1; V[4]=n1-rd(n1/4294967296)*4294967296
        V[3]=V[2]; V[2]=V[1]; V[1]=V[0]; n1=T1+T2; V[0]=n1-rd(n1/4294967296)*4294967296
    for i in range(8):
        n1=H[i]+V[i]; H[i]=n1-rd(n1/4294967296)*4294967296
def wordsBytes(W):
    B=[0.0]*32
    for i in range(8):
        v=W[i]; B[4*i]=rd(v/16777216); v-=B[4*i]*16777216; B[4*i+1]=rd(v/65536); v-=B[4*i+1]*65536
        B[4*i+2]=rd(v/256); B[4*i+3]=v-B[4*i+2]*256
    return B
def authInit(key):
    blk=[54.0]*64
    for i in range(32): blk[i]=float(key[i]^54)
    I=list(H0); shaBlock(I,blk)
    blk=[92.0]*64
    for i in range(32): blk[i]=float(key[i]^92)
    O=list(H0); shaBlock(O,blk)
    return I,O
def hmac50(I,O,lbl,a,b):
    H=list(I); blk=[0.0]*64
    for i in range(18): blk[i]=lbl[i]
    for i in range(16): blk[18+i]=a[i]; blk[34+i]=b[i]
    blk[50]=128; blk[62]=3; blk[63]=144
    shaBlock(H,blk); inner=wordsBytes(H)
    H=list(O); blk=[0.0]*64
    for i in range(32): blk[i]=inner[i]
    blk[32]=128; blk[62]=3; blk[63]=0
    shaBlock(H,blk); return bytes(int(x) for x in wordsBytes(H))
def hexBytes(s,n):
    out=[0.0]*n
    if len(s)!=2*n: return None
    for j in range(2*n):
        c=ord(s[j])
        if 48<=c<=57: d=c-48
        elif 97<=c<=102: d=c-87
        elif 65<=c<=70: d=c-55
        else: return None
        if j==2*rd(j/2): out[rd(j/2)]=d*16
        else: out[rd(j/2)]+=d
    return out
def bytesHex(b):
    s=''
    for x in b:
        d=rd(x/16); s+=chr((48 if d<10 else 87)+d); d=x-16*rd(x/16); s+=chr(int((48 if d<10 else 87)+d))
    return s
def numBytes(v,at,out):
    v=rd(abs(v))
    for i in range(7,-1,-1):
        out[at+i]=v-256*rd(v/256); v=rd(v/256)
LC=[float(c) for c in b'robotlink3 client ']; LS=[float(c) for c in b'robotlink3 server ']; LN=[float(c) for c in b'robotlink3 nonce  ']
for trial in range(200):
    key=os.urandom(32); keyhex=key.hex() if trial%2 else key.hex().upper()
    kb=hexBytes(keyhex,32); assert [int(x) for x in kb]==list(key)
    I,O=authInit([int(x) for x in kb])
    a=os.urandom(16); b=os.urandom(16)
    for lbl,L in ((b'robotlink3 client ',LC),(b'robotlink3 server ',LS),(b'robotlink3 nonce  ',LN)):
        got=hmac50(I,O,L,[float(x) for x in a],[float(x) for x in b])
        assert got==hmac.new(key,lbl+a+b,hashlib.sha256).digest(), trial
    assert bytesHex([float(x) for x in a])==a.hex()
    out=[0.0]*16; v=int.from_bytes(os.urandom(6),'big'); numBytes(float(v),8,out); assert bytes(int(x) for x in out[8:])==v.to_bytes(8,'big')
# the golden vector of PROTOCOL.md / auth.rs
key=bytes(range(32)); I,O=authInit(list(key))
ns=bytes.fromhex('00112233445566778899aabbccddeeff'); nc=bytes.fromhex('0f0e0d0c0b0a09080706050403020100')
assert bytesHex(hmac50(I,O,LC,list(ns),list(nc))) == '4ec766f0727bc30b25adf756b618a2c0e144ae5264ce98c49f27cf6557f13cb2'
assert bytesHex(hmac50(I,O,LS,list(ns),list(nc))) == '37719446d95386f3d2945a059f0b2c06a0a29f965a826f65eda2f6dab93cbfcf'
print("VAL3 arithmetic transliteration matches hashlib/hmac on 200 random keys")
